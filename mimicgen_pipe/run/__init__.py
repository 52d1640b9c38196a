"""Running stages: the generation runner, the parse and pose_noise stages' stores, executors
(local, Ray), resumable work, the arithmetic pins, progress. Imports core, method and data."""
