"""Fit reports: figures (`brdffit.report.figures`) and their assembly into Markdown and self-contained HTML.

`write_report` and `format_value` are imported on first use, so that the helper process that draws figures
(`brdffit.report.worker`) loads matplotlib, not the engine behind the figures' computations."""

__all__ = ["write_report", "format_value"]


def __getattr__(name: str):
    if name in __all__:
        from . import assemble

        return getattr(assemble, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
