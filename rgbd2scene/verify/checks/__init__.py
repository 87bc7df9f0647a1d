"""The registered checks of ``verify``, one module each; :data:`CHECKS` runs them in this order.

Adding a check (say, instrument poses against the segmentation): write ``checks/instruments.py`` with a
:class:`~rgbd2scene.verify.framework.Check` subclass (``names``, ``maps``, ``check_eye`` and/or ``check_pair``;
see ``verify/framework.py``), then add one line to :data:`CHECKS` below. Its rows appear in the report after
those of the checks listed before it.
"""

from rgbd2scene.verify.checks.correspondence import CorrespondenceCheck
from rgbd2scene.verify.checks.coverage import CoverageCheck
from rgbd2scene.verify.checks.depth import DepthCheck
from rgbd2scene.verify.checks.disparity import DisparityCheck
from rgbd2scene.verify.checks.flow import FlowCheck
from rgbd2scene.verify.checks.normals import NormalsCheck
from rgbd2scene.verify.checks.occlusion import OcclusionCheck
from rgbd2scene.verify.checks.schema import SchemaCheck
from rgbd2scene.verify.checks.segmentation import SegmentationCheck
from rgbd2scene.verify.checks.stereo import StereoCheck

CHECKS = (
    SchemaCheck(),
    CoverageCheck(),
    DepthCheck(),
    NormalsCheck(),
    SegmentationCheck(),
    DisparityCheck(),
    FlowCheck(),
    StereoCheck(),
    CorrespondenceCheck(),
    OcclusionCheck(),
)

__all__ = ["CHECKS"]
