"""mimicgen-pipe: MimicGen data generation as a pipeline of DVC stages (see README.md)."""
