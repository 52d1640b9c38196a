"""Where the observation cameras (envs.CAMERAS, named as robomimic names them) sit; every
back end's render.py renders them. Free of simulator imports.

- ``agentview``: fixed, in front of the table, facing the arm across the workspace: arm,
  gripper and objects in one view.
- ``eye_in_hand``: on the Franka hand, where ManiSkill's ``panda_wristcam`` mounts its camera
  (the URDF's realsense mount on ``panda_hand``), looking along the fingers. Every arm of
  both back ends carries the Franka hand, so every arm has it.

World frame, metres; the table top is z = 0 with the workspace around the origin on both
back ends (the robot base at x = -0.615 on ManiSkill, -0.5 on PyBullet).
"""

from __future__ import annotations

import numpy as np

# agentview: eye and target [m, world], vertical field of view [rad]
AGENTVIEW_EYE, AGENTVIEW_TARGET, AGENTVIEW_FOV = (0.6, 0.0, 0.6), (-0.3, 0.0, 0.15), 1.0

# eye_in_hand, in the panda_hand frame (z along the fingers, x across them): the camera's
# position [m], its viewing direction and its image's up direction; vertical field of view
# [rad] as panda_wristcam's
WRIST_POS = np.array([0.0465, -0.02, 0.036])
WRIST_FORWARD = np.array([0.0, 0.0, 1.0])
WRIST_UP = np.array([1.0, 0.0, 0.0])
WRIST_FOV = np.pi / 2
