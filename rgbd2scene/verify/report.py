"""The result of ``verify``: :class:`VerifyReport` (``report.ok``, JSON via ``to_dict``) and its text table."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from rgbd2scene.verify.framework import CheckResult

#: Worst status of a check over its rows, least to most severe.
STATUS_ORDER = ("skip", "info", "pass", "warn", "fail")


@dataclass
class VerifyReport:
    dataset: str
    width: int
    height: int
    frames: int
    mesh: str | None
    results: list[CheckResult] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    seconds: float = 0.0
    seconds_per_frame: float = float("nan")
    notes: list[str] = field(default_factory=list)
    error_maps: list[str] = field(default_factory=list)  # PNGs written with ``verify_dataset(error_maps=DIR)``

    @property
    def ok(self) -> bool:
        return all(r.status != "fail" for r in self.results) and bool(self.results)

    @property
    def failed(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == "fail"]

    def status_of(self, check: str) -> str:
        """Worst status of one check over its rows: fail > warn > pass > info > skip ("absent" without rows)."""
        rows = [r.status for r in self.results if r.check == check]
        return max(rows, key=STATUS_ORDER.index) if rows else "absent"

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ok"] = self.ok
        return d


def fmt(value: float | None, unit: str) -> str:
    """A figure for the report: 4 significant digits, scientific when tiny or huge, "-" when missing."""
    if value is None or not np.isfinite(value):
        return "-"
    if value == 0:
        s = "0"
    elif abs(value) >= 1e4 or abs(value) < 1e-3:
        s = f"{value:.2e}"
    else:
        s = f"{value:.4g}"
    return f"{s} {unit}".strip()


def format_report(report: VerifyReport, max_problems: int = 20) -> str:
    """Plain-text table (check, eye, frames, metric, value, tolerance, result), problems, verdict."""
    header = ("check", "eye", "frames", "metric", "value", "tolerance", "result")
    rows = []
    for r in report.results:
        worst = f" (worst {r.worst_frame})" if r.frames > 1 else ""
        frames = f"{r.frames}{worst}" if r.frames else "-"
        if r.tolerance is None:
            tol = "-"
        else:
            op = ">=" if r.check == "coverage" else "<="
            tol = f"{op} {fmt(r.tolerance, r.unit)}"
        result = r.status.upper() if r.status in ("fail", "warn") else r.status
        metric = r.metric if not r.note or r.status != "skip" else f"{r.metric} ({r.note})"
        rows.append((r.check, r.eye, frames, metric, fmt(r.value, r.unit), tol, result))
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(header)]
    line = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [f"dataset {report.dataset}: {report.width}x{report.height}, {report.frames} frames; "
           f"mesh {report.mesh or '(none)'}", line.format(*header), line.format(*("-" * w for w in widths))]
    out += [line.format(*row) for row in rows]
    if report.notes:
        out.append("")
        out += [f"note: {n}" for n in report.notes]
    if report.problems:
        out.append("")
        out.append(f"problems ({len(report.problems)}):")
        out += [f"  {p}" for p in report.problems[:max_problems]]
        if len(report.problems) > max_problems:
            out.append(f"  ... and {len(report.problems) - max_problems} more")
    if report.error_maps:
        out.append("")
        out.append(f"error maps ({len(report.error_maps)}):")
        out += [f"  {p}" for p in report.error_maps]
    failed = report.failed
    warns = [r for r in report.results if r.status == "warn"]
    verdict = "PASS" if report.ok else f"FAIL ({len(failed)} failed: " + ", ".join(
        sorted({f'{r.check}/{r.eye}' for r in failed})) + ")"
    if warns:
        verdict += f"; {len(warns)} warning(s)"
    out.append("")
    out.append(f"{verdict}  [{report.seconds:.1f} s]")
    return "\n".join(out)
