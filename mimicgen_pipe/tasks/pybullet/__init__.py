"""The PyBullet tasks: each module ``<task>.py`` defines ``TASK``, a
PyBulletTask (mimicgen_pipe.backends.pybullet.tasks), found by name (the registry)."""
