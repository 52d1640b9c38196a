"""Running stages: the generation runner, executors (local, Ray), resumable work, the
arithmetic pins, progress. Imports core, method and data."""
