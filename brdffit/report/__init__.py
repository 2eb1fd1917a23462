"""Fit reports: figures (`brdffit.report.figures`) and their assembly into Markdown and self-contained HTML."""

from .assemble import format_value, write_report

__all__ = ["write_report", "format_value"]
