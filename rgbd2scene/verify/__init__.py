"""Self-consistency checks of a rendered dataset against ray casting and the other maps."""

from rgbd2scene.verify.driver import Tolerances, VerifyReport, format_report, verify_dataset

__all__ = ["Tolerances", "VerifyReport", "format_report", "verify_dataset"]
