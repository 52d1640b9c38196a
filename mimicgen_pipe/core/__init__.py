"""The shared vocabulary: poses, kinematics, the controller, task specs, reset variants,
observations, the contracts a back end implements, the registry, the observation cameras'
placement, URDF composition, errors and small file helpers. Imports nothing else of the
package."""
