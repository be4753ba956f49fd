"""ROS-free processing stages (the OpenREALM pattern).

Each stage owns its state and a typed statistics record (:class:`StageStats`)
and hands its results back as return values; nothing here imports rclpy. The
nodes (``subpix_ros.nodes``) are thin adapters around these stages, and
:class:`Pipeline` chains them in one thread for offline processing, a
notebook or a batch job.
"""

from subpix_ros.stages.mosaic import MosaicStage
from subpix_ros.stages.pipeline import Pipeline
from subpix_ros.stages.reconstruction import FrameSet, ReconstructionStage
from subpix_ros.stages.registration import RegistrationStage
from subpix_ros.stages.shift import ShiftStage
from subpix_ros.stages.stats import (
    MosaicStats,
    ReconstructionStats,
    RegistrationStats,
    ShiftStats,
    StageStats,
    StageTimes,
)
from subpix_ros.stages.types import Aligned, Frame, NewReference, Shift, Skipped, SuperResolved

__all__ = [
    "Aligned",
    "Frame",
    "FrameSet",
    "MosaicStage",
    "MosaicStats",
    "NewReference",
    "Pipeline",
    "ReconstructionStage",
    "ReconstructionStats",
    "RegistrationStage",
    "RegistrationStats",
    "Shift",
    "ShiftStage",
    "ShiftStats",
    "Skipped",
    "StageStats",
    "StageTimes",
    "SuperResolved",
]
