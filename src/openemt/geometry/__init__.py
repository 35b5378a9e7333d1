"""Batched SE(3) geometry: poses, pose vectors, pose errors and the fixture kinematics."""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._fixtures": ("FIXTURE_CODE_RE", "SENSOR_FIXTURES", "SOURCE_FIXTURES", "fixture_axes",
                   "ground_truth_poses", "sensor_fixture_rotation", "source_fixture_rotation",
                   "stage_joint", "stage_transform"),
    "._motion": ("MIN_SECOND_AXIS_DEG", "RotationDiversity", "require_rotation_diversity",
                 "rotation_diversity"),
    "._pose": ("adjoint", "check_points", "check_pose_vectors", "check_poses", "compose",
               "error_magnitudes", "invert", "left_jacobian_so3", "nearest_rotation", "pose_error",
               "pose_from_rt", "pose_from_vector", "rotation_x", "rotation_y", "rotation_z",
               "rotvec_between", "skew", "vector_from_pose"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
