"""The tasks, one file each under tasks/<backend>/ (``<task>.py`` defines ``TASK``; see
docs/tasks.md). Imports core and the back ends (its back end's task base,
mimicgen_pipe.backends.<backend>.tasks); the back end finds a task by name through the
registry. A stage depends on its own task's file, not on every task's."""
