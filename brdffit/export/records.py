"""The fit option's exports recorded beside a fit: ``exports.json`` in a `brdffit fit` output folder.

`brdffit export RESULT.h5 --to T --fit` writes the renderer's own model fitted to the result, with the achieved
error in its comments. When RESULT.h5 is the ``result.h5`` of a `brdffit fit` output folder, `record` also notes
what was written in ``exports.json`` beside it, so that the report (`brdffit report`,
`brdffit.report.write_report`) states the achieved error next to the direct mapping's (docs/report.md). This
module alone reads and writes that file::

    {"format": "brdffit exports", "version": 1, "exports": [RECORD, ...]}

with one RECORD (`ExportRecord.to_dict`) per target and exported model: a later export of the same model to the
same target replaces the earlier record. The file is replaced atomically (a temporary file beside it, then a
rename), and one that cannot be read is never overwritten.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import numbers
from pathlib import Path

from ..output_folder import FOLDER

__all__ = ["EXPORTS_FILE", "ExportRecord", "ExportLog", "exports_path", "read", "record"]

EXPORTS_FILE = FOLDER.exports
FORMAT, VERSION = "brdffit exports", 1


@dataclasses.dataclass(frozen=True)
class ExportRecord:
    """What one export under the fit option wrote.

    Attributes:
        target: the renderer (a name in `brdffit.export.TARGETS`).
        source: the exported model as `brdffit.models.model_to_dict` describes it: the fit the record belongs to.
        written: the spec of the model whose mapping was written (`Export.mapped`).
        fitted: the comment line naming the fit that was written (`Export.fitted`); None where the direct mapping
            was closer (or exact) and was written.
        rms: the achieved cosine-weighted relative RMS error of what was written (`Deviation.rms`).
        max_rel: its largest relative error (`Deviation.max_rel`).
        approximations: the approximations stated in the comments (`Export.notes`).
        exact: whether the comments call the export exact.
        date: when it was written, UTC, ISO 8601.
        out: the file it was written to; None where it was printed.
    """

    target: str
    source: dict
    written: str
    fitted: str | None
    rms: float
    max_rel: float
    approximations: tuple
    exact: bool
    date: str
    out: str | None

    @classmethod
    def of(cls, export, to: str, out=None) -> ExportRecord:
        """The record of an export written now.

        Arguments:
            export: the `brdffit.export.Export`.
            to: its target's name.
            out: the file it was written to (None: printed).

        Returns:
            The `ExportRecord`.
        """
        from ..models import model_to_dict

        return cls(target=to, source=model_to_dict(export.source), written=export.mapped.spec,
                   fitted=export.fitted, rms=float(export.deviation.rms), max_rel=float(export.deviation.max_rel),
                   approximations=tuple(export.notes), exact=export.exact,
                   date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                   out=None if out is None else str(out))

    def to_dict(self) -> dict:
        """The record as JSON-ready values (`from_dict` reads them back)."""
        return dict(dataclasses.asdict(self), approximations=list(self.approximations))

    @classmethod
    def from_dict(cls, entry: dict) -> ExportRecord:
        """The record `to_dict` wrote (the values checked by `read`)."""
        return cls(**dict(entry, rms=float(entry["rms"]), max_rel=float(entry["max_rel"]),
                          approximations=tuple(entry["approximations"])))

    def describes(self, model) -> bool:
        """Whether the record is of this model (its spec, channels and parameter values); False for None."""
        from ..models import model_to_dict

        return model is not None and self.source == model_to_dict(model)


def _is_number(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


# What each field of a record holds: (check, what the message calls it).
_FIELDS = {
    "target": (lambda v: isinstance(v, str), "a string"),
    "source": (lambda v: isinstance(v, dict), "an object"),
    "written": (lambda v: isinstance(v, str), "a string"),
    "fitted": (lambda v: v is None or isinstance(v, str), "a string or null"),
    "rms": (_is_number, "a number"),
    "max_rel": (_is_number, "a number"),
    "approximations": (lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v), "a list of strings"),
    "exact": (lambda v: isinstance(v, bool), "true or false"),
    "date": (lambda v: isinstance(v, str), "a string"),
    "out": (lambda v: v is None or isinstance(v, str), "a string or null"),
}


def _record_from(path, index: int, entry) -> ExportRecord:
    """Record ``index`` of ``path``'s ``exports`` list, checked field by field (unknown fields are ignored).

    Raises:
        brdffit.io.FormatError: not an object, a missing field or one of the wrong type.
    """
    from ..io._common import FormatError

    if not isinstance(entry, dict):
        raise FormatError(path, f"exports[{index}] is not a JSON object")
    for name, (check, kind) in _FIELDS.items():
        if name not in entry:
            raise FormatError(path, f"exports[{index}] has no {name!r}")
        if not check(entry[name]):
            raise FormatError(path, f"exports[{index}].{name} is {json.dumps(entry[name])[:60]}, not {kind}")
    return ExportRecord.from_dict({name: entry[name] for name in _FIELDS})


@dataclasses.dataclass(frozen=True)
class ExportLog:
    """The exports recorded beside a result file.

    Attributes:
        path: its ``exports.json``; None where the result is not in a `brdffit fit` output folder.
        records: the `ExportRecord`s in the order written (empty where the file is absent or unreadable).
        problem: why the file could not be read, naming it; None where it could (or is absent).
    """

    path: Path | None
    records: tuple = ()
    problem: str | None = None

    def for_model(self, model) -> list[ExportRecord]:
        """The records of exports of ``model`` (the others belong to another fit in the same folder)."""
        return [r for r in self.records if r.describes(model)]


def exports_path(result_path) -> Path | None:
    """Where the exports of a result file are recorded.

    Arguments:
        result_path: a results file.

    Returns:
        ``exports.json`` beside it when it is the ``result.h5`` of a `brdffit fit` output folder (its
        ``result.json`` beside it), else None.
    """
    result_path = Path(result_path)
    # `brdffit fit` writes both into every output folder: a result file beside its JSON summary is one.
    if result_path.name != FOLDER.results or not (result_path.parent / FOLDER.summary_json).is_file():
        return None
    return result_path.parent / EXPORTS_FILE


def _load(path: Path) -> tuple:
    """The records of an ``exports.json`` (none where it is absent).

    Raises:
        brdffit.io.FormatError: not a regular file of bounded size, not UTF-8 JSON, not this layout.
    """
    from ..io._common import FormatError, decode_text, parse_meta_json, read_file_bytes

    try:
        data = read_file_bytes(path)
    except FileNotFoundError:
        return ()
    content = parse_meta_json(path, decode_text(path, data, "a JSON file"), "the file")
    layout = isinstance(content, dict) and content.get("format") == FORMAT
    if not layout or not isinstance(content.get("exports"), list):
        raise FormatError(path, f"not brdffit's record of exports (a JSON object with \"format\": \"{FORMAT}\" "
                                "and an \"exports\" list)")
    if content.get("version") != VERSION:
        raise FormatError(path, f"version {json.dumps(content.get('version'))}; this brdffit reads version {VERSION}")
    return tuple(_record_from(path, i, entry) for i, entry in enumerate(content["exports"]))


def read(result_path) -> ExportLog:
    """The exports recorded beside a result file; a file that cannot be read is a value, not an exception.

    Arguments:
        result_path: a results file.

    Returns:
        An `ExportLog`: no records where the result is not in an output folder or nothing was recorded; with
        ``problem`` set (the message names the file) where ``exports.json`` cannot be read.
    """
    from ..io._common import FormatError

    path = exports_path(result_path)
    if path is None:
        return ExportLog(None)
    try:
        return ExportLog(path, _load(path))
    except FormatError as exc:
        return ExportLog(path, (), str(exc))


def record(result_path, export, to: str, out=None) -> Path | None:
    """Record an export under the fit option beside the result file it came from.

    Arguments:
        result_path: the results file that was exported.
        export: the `brdffit.export.Export` that was written.
        to: its target's name.
        out: the file it was written to (None: printed).

    Returns:
        The ``exports.json`` written, or None where the result is not in a `brdffit fit` output folder (nothing
        is written).

    Raises:
        brdffit.io.FormatError: the existing ``exports.json`` cannot be read; it is left as it is.
    """
    from ..io._common import atomic_path
    from ..io.locking import locked

    path = exports_path(result_path)
    if path is None:
        return None
    with locked(path):  # concurrent exports into one folder: each reads what the one before it wrote
        earlier = _load(path)
        new = ExportRecord.of(export, to, out)
        kept = [r for r in earlier if (r.target, r.source) != (new.target, new.source)]
        text = json.dumps({"format": FORMAT, "version": VERSION, "exports": [r.to_dict() for r in kept + [new]]},
                          indent=2)
        with atomic_path(path) as tmp:
            tmp.write_text(text + "\n", encoding="utf-8")
    return path
