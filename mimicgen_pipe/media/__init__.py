"""Pictures of episodes: camera images and videos. Imports core, method, data and run."""
