"""Report and metrics paths of a project folder, for the eval report tests (the layout spells the names)."""

from pathlib import Path

from eval.report import ReportPaths, build_report, write_report
from hybridsplat.layout import ProjectLayout


def metrics_file(project):
    return ProjectLayout(project).metrics_json


def build_project_report(project, units=None):
    layout = ProjectLayout(project)
    return build_report(layout.manifest, layout.metrics_json, units)


def write_project_report(project, out=None, **options):
    """The report as the report stage writes it: with the notes it reads from the stages' recorded results."""
    from hybridsplat.stages.report import run_notes

    layout = ProjectLayout(project)
    out = Path(out) if out is not None else layout.report_dir
    paths = ReportPaths(out / "report.json", out / "report.md", out / "report.html")
    options.setdefault("notes", run_notes(layout))
    return write_report(layout.manifest, layout.metrics_json, paths, **options)
