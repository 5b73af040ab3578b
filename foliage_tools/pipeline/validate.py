"""``foliage validate``: run the checks and decide pass/fail."""

from __future__ import annotations

from pathlib import Path

from foliage_tools.pipeline.report import Report
from foliage_tools.scene.validate import ERROR, WARNING, validate
from foliage_tools.pipeline.stats import ValidateStats


def run_validate(path: Path, *, strict: bool) -> tuple[Report[ValidateStats], bool]:
    """Return the report and whether validation failed (errors, or warnings too when ``strict``)."""
    report: Report[ValidateStats] = Report(command="validate", inputs=[str(path)])
    findings = validate(path)
    errors = sum(f.severity == ERROR for f in findings)
    warnings = sum(f.severity == WARNING for f in findings)
    failed = errors > 0 or (strict and warnings > 0)
    report.stats = {
        "findings": [f.as_dict() for f in findings],
        "errors": errors,
        "warnings": warnings,
        "strict": strict,
        "passed": not failed,
    }
    return report.finish(), failed
