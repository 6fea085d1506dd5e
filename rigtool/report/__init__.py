"""Self-contained HTML report of a run (`rigtool report RUN_ID`): figures embedded, no network."""

from rigtool.report.html import REPORT_FILE, render_report, write_report

__all__ = ["REPORT_FILE", "render_report", "write_report"]
