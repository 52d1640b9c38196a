"""The ManiSkill tasks: each module ``<task>.py`` defines ``TASK``, a
ManiSkillTask (mimicgen_pipe.backends.maniskill.tasks), found by name (the registry)."""
