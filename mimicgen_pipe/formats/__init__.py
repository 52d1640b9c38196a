"""Other tools' files: exporters (robomimic, LeRobot, ManiSkill) and policies trained
elsewhere. Imports core, method, data, run and sources."""
