"""The ``brdffit`` command line: a thin layer that parses arguments, calls one API function and prints or writes
its result. Exit codes: 0 success, 1 a fit did not converge, 2 bad input or usage, 130 interrupted (143: `brdffit
posterior` stopped by SIGTERM) (docs/cli.md)."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

from . import __version__
from ._memory import keep_freed_memory
from .compilation_cache import cache_dir, enable_compilation_cache
from .criteria import CRITERIA
from .defaults import FIT, POSTERIOR, TABULATED
from .distributed import DEFAULT_BATCH
from .output_folder import (FOLDER, OutputFolderError, check_output_folder, check_still_free, check_writable,
                            default_out, staged_folder)

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_BAD_INPUT = 0, 1, 2
EXIT_IMPLAUSIBLE = 3  # `brdffit export` refused a renderer material of an implausible fit (--force exports it)
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM: `brdffit posterior` stopped by `kill` or a batch system, as by Ctrl-C
DEFAULT_MODEL = "auto"
# The cyclic garbage collector's thresholds in the console script's own process (`run`): a collection of the
# youngest generation after 10,000 net allocations of container objects instead of Python's 700 (`gc.set_threshold`).
# A fit allocates hundreds of thousands of small containers (pytrees, dicts, matplotlib's artists), and every
# collection holds Python's lock, stopping the selection's threads and the report alike (docs/benchmarks.md).
COLLECTOR_THRESHOLDS = (10_000, 10, 10)
_own_process = False  # set by `run`: this process is the console script's, not a caller's that calls `main`


class UsageError(Exception):
    """A command-line value that cannot be used; reported with exit code 2."""


def bounded(kind=int, low=None, high=None):
    """The argparse ``type`` of a numeric option with its allowed range, declared with the option: e.g.
    ``add_argument("--multistart", type=bounded(int, 0))``. A value outside is a usage error (exit 2) whose message
    names the option (argparse adds it) and the range.

    Arguments:
        kind: int or float.
        low, high: inclusive bounds; None leaves that side open (a float must be finite).
    """
    import math

    word = "an integer" if kind is int else "a finite number"
    allowed = " and ".join(part for part in (f">= {low:g}" if low is not None else "",
                                             f"<= {high:g}" if high is not None else "") if part)
    wanted = f"{word} {allowed}".strip()

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {word} (allowed: {wanted})") from None
        if (kind is float and not math.isfinite(value)) or (low is not None and value < low) or (
                high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text} is outside the allowed range: {wanted}")
        return value

    parse.__name__ = kind.__name__
    return parse


class RegistryNames(Sequence):
    """The names of a registry declared in a module that imports JAX (the synthesis patterns, the tone maps), as an
    option's ``choices``: the module is imported when argparse first checks a value or prints the option's help,
    so the parser is built without JAX and the names are declared once, with what they name.

    Arguments:
        module: the module's import path, e.g. ``"brdffit.render"``.
        attribute: the registry in it (a dict or a sequence of names).
    """

    def __init__(self, module: str, attribute: str):
        self._where = (module, attribute)
        self._names: tuple | None = None

    def _loaded(self) -> tuple:
        if self._names is None:
            import importlib

            module, attribute = self._where
            self._names = tuple(getattr(importlib.import_module(module), attribute))
        return self._names

    def __getitem__(self, index):
        return self._loaded()[index]

    def __len__(self) -> int:
        return len(self._loaded())

    def __contains__(self, name) -> bool:
        return name in self._loaded()


def _check_fixed(fixed: dict, specs) -> None:
    """Refuse a ``--fixed`` value outside its parameter's declared bounds in any of the model ``specs``."""
    from . import models

    for spec in specs:
        declared = {p.name: p for p in models.get(spec, channels=1).param_specs}
        for name, value in fixed.items():
            p = declared.get(name)
            values = value if isinstance(value, list) else [value]
            if p is not None and not all(p.lower <= v <= p.upper for v in values):
                raise UsageError(f"--fixed {name}={','.join(f'{v:g}' for v in values)}: outside the allowed range "
                                 f"of {name}, [{p.lower:g}, {p.upper:g}] (model {spec})")


def _parse_fixed(items) -> dict:
    fixed = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"--fixed {item!r}: write NAME=VALUE, e.g. --fixed f0=0.04")
        name, value = item.split("=", 1)
        try:
            parts = [float(v) for v in value.split(",")]
        except ValueError:
            raise UsageError(f"--fixed {item!r}: {value!r} is not a number (or comma-separated numbers)") from None
        fixed[name.strip()] = parts[0] if len(parts) == 1 else parts
    return fixed


# ------------------------------------------------------------------------------------------- instrument tables
# The options of `brdffit.io.read_table` on the command line, declared once: `_add_table_options` gives them to
# every command that reads measurements, `_table_options` turns them into read_table's keywords, and
# `table_options_doc` writes the table of docs/cli.md (a test checks that the page holds it).
def _column(text: str):
    """A column as read_table takes it: a header name, or a 0-based index where the text is a number."""
    text = text.strip()
    return int(text) if text.isdigit() else text


def _names(text: str) -> list:
    """A comma list of columns."""
    items = [_column(item) for item in text.split(",")]
    if "" in items:
        raise argparse.ArgumentTypeError(f"{text!r}: an empty column name (write NAME[,NAME...])")
    return items


def _columns(text: str) -> dict:
    """KEY=COLUMN pairs as read_table's ``columns`` mapping, with the keys checked."""
    from .io.table import ANGLE_COLUMNS, WEIGHTS_COLUMN

    mapping = {}
    for item in text.split(","):
        key, sep, column = (part.strip() for part in item.partition("="))
        if not sep or not key or not column:
            raise argparse.ArgumentTypeError(f"{item!r}: write KEY=COLUMN pairs separated by commas, e.g. "
                                             "theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir")
        if key not in (*ANGLE_COLUMNS, WEIGHTS_COLUMN):
            raise argparse.ArgumentTypeError(f"unknown key {key!r}; keys are {', '.join(ANGLE_COLUMNS)} and "
                                             f"{WEIGHTS_COLUMN}")
        if key in mapping:
            raise argparse.ArgumentTypeError(f"{key!r} is given twice")
        mapping[key] = _column(column)
    return mapping


def _sigma(text: str):
    """σ columns, or False (read_table's "ignore σ") for 'none'."""
    return False if text.strip() == "none" else _names(text)


def _where(text: str) -> tuple:
    """COLUMN=VALUE as (column, number | list of numbers | text)."""
    column, sep, wanted = (part.strip() for part in text.partition("="))
    if not sep or not column or not wanted:
        raise argparse.ArgumentTypeError(f"{text!r}: write COLUMN=VALUE, e.g. lambda=0.532")
    try:
        numbers = [float(v) for v in wanted.split(",")]
    except ValueError:
        return _column(column), wanted  # text, compared whole
    return _column(column), numbers[0] if len(numbers) == 1 else numbers


def _delimiter(text: str) -> str:
    """One character; 'tab' and 'space' (read_table splits on runs of whitespace) by name."""
    named = {"tab": "\t", "\\t": "\t", "space": " ", "whitespace": " "}
    if text in named:
        return named[text]
    if len(text) != 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give one character, 'tab' or 'space'")
    return text


def _negative(text: str) -> str:
    if text not in ("error", "missing"):
        raise argparse.ArgumentTypeError(f"{text!r}: choose error or missing")
    return text


class _TableOption(NamedTuple):
    """One option of `brdffit.io.read_table` on the command line."""

    flag: str
    keyword: str  # read_table's argument
    metavar: str | None  # None: a switch, which passes ``switched`` when given
    help: str
    parse: Callable | None = None  # the option's text -> the keyword's value
    repeat: bool = False
    switched: object = None
    formats: tuple = ("table",)  # the file formats (brdffit.io.detect_format) the option applies to

    @property
    def dest(self) -> str:
        """The attribute of the parsed arguments."""
        return self.flag[2:].replace("-", "_")


TABLE_OPTIONS = (
    _TableOption("--columns", "columns", "KEY=COLUMN,...",
                 "where the angles (and weights) are: KEY one of theta_i, phi_i, theta_o, phi_o, weights; COLUMN a "
                 "header name or a 0-based index; keys not given take their canonical names", _columns),
    _TableOption("--values", "values", "COLUMN[,COLUMN...]",
                 "the value column(s), one channel each (default: every other numeric column)", _names),
    _TableOption("--sigma", "sigma", "COLUMN[,COLUMN...]|none",
                 "the σ column(s), aligned with --values (default: the column sigma_V of each value column V, "
                 "where present; 'none' ignores σ columns)", _sigma),
    _TableOption("--where", "where", "COLUMN=VALUE[,VALUE...]",
                 "keep the rows whose COLUMN equals VALUE: a number (within a relative 1e-9; a comma list keeps "
                 "any of them) or text (compared whole); repeatable, every filter must hold", _where, repeat=True),
    _TableOption("--channel-column", "channel_column", "COLUMN",
                 "one channel per distinct value of COLUMN (e.g. lambda), pairing rows with the same four angles; "
                 "NaN where a geometry lacks a row", _column),
    _TableOption("--channels", "channels", "NAME[,NAME...]",
                 "the channels' names (default: the value columns' headers)",
                 lambda text: [name.strip() for name in text.split(",")]),
    _TableOption("--radians", "degrees", None, "the angle columns are in radians (default: degrees for tables; ASTM "
                 "E1392 files: decided from the data)", switched=False, formats=("table", "astm")),
    _TableOption("--degrees", "degrees", None, "ASTM E1392 files: the angles are in degrees (default: decided from "
                 "the data, radians where every θ is within π/2)", switched=True, formats=("astm",)),
    _TableOption("--delimiter", "delimiter", "D",
                 "the cell separator: one character, 'tab' or 'space' (runs of whitespace); default: a tab for .tsv "
                 "or a tab in the first line, else ',', else ';', else whitespace", _delimiter),
    _TableOption("--negative", "negative", "error|missing",
                 "a negative value is an error (default) or, with 'missing', a missing value (NaN)", _negative),
)
TABLE_GROUP = "instrument tables (CSV/TSV/text files; the options of brdffit.io.read_table, --radians and --degrees "\
    "also of ASTM E1392 files)"
# How `_load`'s refusal names the formats an option applies to.
_FORMAT_WORDS = {"table": "instrument tables (CSV/TSV/text)", "astm": "ASTM E1392 files",
                 "merl": "tabulated files (MERL, RGL-EPFL)", "rgl": "tabulated files (MERL, RGL-EPFL)"}


def _sampling(text: str) -> str:
    from .io.tabulated import SAMPLINGS

    if text not in SAMPLINGS:
        raise argparse.ArgumentTypeError(f"{text!r}: choose {' or '.join(SAMPLINGS)}")
    return text


def _max_theta(text: str) -> float:
    import math

    try:
        degrees = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give an angle in degrees") from None
    if not 0 < degrees <= 90:
        raise argparse.ArgumentTypeError(f"{text!r}: give an angle in (0, 90] degrees")
    return math.radians(degrees)


# The options of a tabulated file's reading (`brdffit.io.tabulated`: MerlTable / RglTable.to_measurements).
TABULATED_OPTIONS = (
    _TableOption("--sampling", "sampling", "directions|grid",
                 "what the fit is given: the file's interpolation at importance-weighted direction pairs "
                 "(directions, the default) or the file's own grid nodes with their weights (grid)", _sampling,
                 formats=("merl", "rgl")),
    _TableOption("--pairs", "pairs", "N",
                 f"the number of direction pairs of --sampling directions (default {TABULATED.pairs})",
                 bounded(int, 1), formats=("merl", "rgl")),
    _TableOption("--max-theta", "max_theta", "DEG",
                 f"the largest polar angle of the direction pairs, degrees (default {TABULATED.max_theta_deg:g})",
                 _max_theta, formats=("merl", "rgl")),
)
TABULATED_GROUP = "tabulated files (MERL .binary, RGL-EPFL .bsdf; brdffit.io.tabulated)"
READ_OPTIONS = TABLE_OPTIONS + TABULATED_OPTIONS


def _add_table_options(p) -> None:
    """Give a command that reads measurements the options of `brdffit.io.read_table` and of a tabulated file's
    reading."""
    for title, options in ((TABLE_GROUP, TABLE_OPTIONS), (TABULATED_GROUP, TABULATED_OPTIONS)):
        group = p.add_argument_group(title)
        _add_options(group, options)


def _add_options(group, options) -> None:
    for option in options:
        if option.metavar is None:
            group.add_argument(option.flag, dest=option.dest, action="store_true", help=option.help)
        else:
            group.add_argument(option.flag, dest=option.dest, metavar=option.metavar, type=option.parse,
                               help=option.help, action="append" if option.repeat else "store")


def _given(args) -> list:
    """The reading options given on the command line."""
    given = [o for o in READ_OPTIONS
             if (getattr(args, o.dest, None) if o.metavar is None else getattr(args, o.dest, None) is not None)]
    keywords = [o.keyword for o in given]
    for keyword in {k for k in keywords if keywords.count(k) > 1}:
        raise UsageError(" and ".join(o.flag for o in given if o.keyword == keyword) + " contradict each other: give "
                         "one")
    return given


def _table_options(args) -> dict:
    """The reader keywords of the reading options (table and tabulated) given on the command line."""
    options = {}
    for option in _given(args):
        given = getattr(args, option.dest, None)
        if option.metavar is None:
            options[option.keyword] = option.switched
        elif option.repeat:
            merged = {}
            for key, value in given:
                if key in merged:
                    raise UsageError(f"{option.flag} {key}: the column is filtered twice; give its values once as a "
                                     "comma list")
                merged[key] = value
            options[option.keyword] = merged
        else:
            options[option.keyword] = given
    return options


def _cell(text: str) -> str:
    return text.replace("|", "\\|")  # a pipe inside a Markdown table cell, code spans included


def table_options_doc() -> str:
    """The Markdown table of the table options (docs/cli.md holds it; a test checks it is current)."""
    rows = ["| option | files | meaning |", "|---|---|---|"]
    for option in READ_OPTIONS:
        usage = option.flag if option.metavar is None else f"{option.flag} {option.metavar}"
        rows.append(f"| `{_cell(usage)}` | {', '.join(option.formats)} | {_cell(option.help)} |")
    return "\n".join(rows) + "\n"


def _load(path, args):
    """The measurements in a file, read with the command's table options; loads neither JAX nor the models.

    Raises:
        UsageError: table options for a file that is not a table. FileNotFoundError, FormatError,
            MeasurementError: from the reader, naming the file.
    """
    from . import io

    path = Path(path)
    options = _table_options(args)
    try:
        if not options:
            return io.load(path)
        kind = io.detect_format(path)  # a missing path, a directory, a FIFO, ... is refused here
        misplaced = [o for o in _given(args) if kind not in o.formats]
        if misplaced:
            verb = "apply" if len(misplaced) > 1 else "applies"
            where = " and ".join(dict.fromkeys(_FORMAT_WORDS[f] for f in misplaced[0].formats))
            raise UsageError(f"{path} is a {kind} file; {', '.join(o.flag for o in misplaced)} {verb} to {where} "
                             "only: read it without")
        return io.load(path, format=kind, **options)
    except io.FormatError as exc:
        # read_table names a missing angle column "angle theta_i: no column ..."; say how to name it here.
        if not exc.problem.startswith("angle ") or "no column" not in exc.problem:
            raise
        raise io.FormatError(exc.path, exc.problem + "; name the file's angle columns with --columns "
                             "theta_i=NAME,phi_i=NAME,theta_o=NAME,phi_o=NAME (see --help)") from None


def _job(args, measurements) -> str:
    """The words that decide a command's compiled programs, for `enable_compilation_cache`'s prefetch: the command,
    its options (not the file, the output folder or how the result is printed) and the data's shape (samples,
    channels)."""
    skipped = {"run", "command", "file", "result", "out", "json", "quiet", "force"}
    options = sorted((k, repr(v)) for k, v in vars(args).items() if k not in skipped)
    return f"{args.command} {options} {measurements.n}x{measurements.n_channels}"


def _cmd_models(args) -> int:
    from . import models

    for name in models.names():
        cls = models.lobe_class(name)
        print(models.describe(cls))
        for spec in cls().param_specs():  # the declarations: no model is built, so JAX is not loaded
            fixed = ", fixed by default" if spec.fixed else ""
            print(f"    {spec.name:<10} {spec.kind:<6} default {spec.default:<8g} bounds [{spec.lower:g}, "
                  f"{spec.upper:g}] unit {spec.unit}{fixed}: {spec.doc}")
    return EXIT_OK


INCIDENCES_LISTED = 12  # `brdffit info` lists the θi of at most this many incidences


def _incidences(m) -> tuple[int, list[float] | None]:
    """The number of distinct incident directions and, when there are few, their θi in degrees (sorted).

    Directions are compared as unit vectors rounded to 1e-9, so that φi is irrelevant at θi = 0 and 0 equals 2π.
    """
    import numpy as np

    wi = np.round(m.wi(), 9) + 0.0  # + 0.0 turns -0.0 into 0.0
    _, first = np.unique(wi, axis=0, return_index=True)
    if len(first) > INCIDENCES_LISTED:
        return len(first), None
    return len(first), sorted(round(float(np.degrees(t)), 6) for t in m.theta_i[first])


def describe(m, path) -> dict:
    """What `brdffit info` shows of measurements read from ``path``, as one JSON-serialisable dict.

    Arguments:
        m: the `Measurements`.
        path: the file they were read from.

    Returns:
        ``file``, ``format`` and ``description`` (from ``m.meta``, None when absent), ``samples``, ``channels``,
        ``incidences`` (distinct (θi, φi) directions) and ``incidence_theta_i_deg`` (their θi, when at most
        `INCIDENCES_LISTED`), the angle ranges in degrees, ``value_range`` (1/sr), ``missing`` (values that are
        NaN, of samples x channels) and ``missing_fraction``, ``sigma`` and ``weights`` (present or not),
        ``weights_total``, ``read`` (``meta["read"]``: what the reader reports, e.g. values clipped) and ``meta``.
    """
    import numpy as np

    deg = np.degrees
    valid = np.isfinite(m.values)
    incidences, theta_list = _incidences(m)
    return {
        "file": str(path),
        "format": m.meta.get("format"),
        "description": m.meta.get("description"),
        "samples": m.n,
        "channels": list(m.channels),
        "incidences": incidences,
        "incidence_theta_i_deg": theta_list,
        "theta_i_deg": [float(deg(m.theta_i.min())), float(deg(m.theta_i.max()))],
        "theta_o_deg": [float(deg(m.theta_o.min())), float(deg(m.theta_o.max()))],
        "phi_o_deg": [float(deg(m.phi_o.min())), float(deg(m.phi_o.max()))],
        "value_range": [float(np.nanmin(m.values)), float(np.nanmax(m.values))] if valid.any() else None,
        "missing": int(valid.size - valid.sum()),
        "missing_fraction": float(1.0 - valid.mean()),
        "sigma": m.sigma is not None,
        "weights": m.weights is not None,
        "weights_total": None if m.weights is None else float(np.sum(m.weights)),
        "read": dict(m.meta.get("read") or {}),
        "meta": m.meta,
    }


def _shown(value) -> str:
    """A meta value as `brdffit info` prints it: numbers with 6 significant digits, containers as JSON."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (dict, list)):
        return json.dumps(value)
    return str(value)


def _cmd_info(args) -> int:
    m = _load(args.file, args)
    info = describe(m, args.file)
    if args.json:
        print(json.dumps(info, indent=2))
        return EXIT_OK
    lines = [f"{info['file']}: {m.n} samples x {m.n_channels} channel{'s' if m.n_channels != 1 else ''} "
             f"({', '.join(m.channels)})"]
    for key in ("format", "description"):
        if info[key] is not None:
            lines.append(f"  {key}: {_shown(info[key])}")
    listed = info["incidence_theta_i_deg"]
    lines.append(f"  incidences: {info['incidences']}"
                 + (f" (theta_i {', '.join(f'{t:g}' for t in listed)} deg)" if listed else ""))
    (ti0, ti1), (to0, to1), (po0, po1) = info["theta_i_deg"], info["theta_o_deg"], info["phi_o_deg"]
    lines.append(f"  theta_i {ti0:.1f}..{ti1:.1f} deg, theta_o {to0:.1f}..{to1:.1f} deg, "
                 f"phi_o {po0:.1f}..{po1:.1f} deg")
    if info["value_range"]:
        lines.append(f"  values {info['value_range'][0]:.4g}..{info['value_range'][1]:.4g} 1/sr")
    lines.append(f"  missing: {info['missing']} of {m.values.size} values ({100 * info['missing_fraction']:.2f}%)")
    weights = f"yes, total {info['weights_total']:.6g}" if m.weights is not None else "no"
    lines.append(f"  sigma: {'yes' if info['sigma'] else 'no'}, weights: {weights}")
    if info["read"]:
        lines.append("  read:")
        lines.extend(f"    {key}: {_shown(value)}" for key, value in info["read"].items())
    if "truth" in m.meta:
        lines.append(f"  ground truth: {m.meta['truth']['spec']} {json.dumps(m.meta['truth']['params'])}")
    print("\n".join(lines))
    return EXIT_OK


def _with_lobes(spec: str, k: int) -> str:
    """The spec with every Lafortune lobe set to k sub-lobes."""
    from . import models

    tokens = []
    found = False
    for name, options in models.parse_spec(spec):
        if name == "lafortune":
            found = True
            options = dict(options, lobes=k)
            if options == {"lobes": 1}:
                options = {}
        inner = ", ".join(f"{key}={value}" for key, value in options.items())
        tokens.append(name + (f"({inner})" if inner else ""))
    if not found:
        raise UsageError(f"--lobes needs a model with a Lafortune lobe, e.g. --model lambert+lafortune; got {spec!r}")
    return "+".join(tokens)


def _fit_options(args) -> dict:
    return dict(loss=args.loss, solver=args.solver, fixed=_parse_fixed(args.fixed), seed=args.seed,
                max_steps=args.max_steps)


def _progress(args) -> bool:
    """Progress lines go to stderr unless the user asked for quiet or machine-readable output."""
    return not (getattr(args, "quiet", False) or getattr(args, "json", False))


def _cmd_fit(args) -> int:
    path = Path(args.file)
    out = Path(args.out) if args.out else default_out(path)
    check_writable(out)
    check_output_folder(out, args.force)
    worker = _drawing_worker() if args.report else None  # its imports run while this process reads and fits
    try:
        measurements = _load(path, args)  # first: a file that cannot be read is reported before JAX is loaded
        return _fit_and_write(args, out, measurements, worker)
    finally:
        if worker is not None:
            worker.close()


def _fit_and_write(args, out: Path, measurements, worker) -> int:
    """`_cmd_fit` once the data are read: fit or select, write the results folder and print the summary (its report
    partly drawn by ``worker``, a `brdffit.report.worker.DrawingWorker`, where there is one)."""
    from . import fit, io, select

    _engine_loaded(_job(args, measurements))
    if args.report:
        _import_in_background("brdffit.report.assemble")
    selection = None
    if args.target is not None and (args.model != "auto" or args.lobes is not None):
        raise UsageError(f"--for {args.target} chooses among the models {args.target} represents exactly; give it "
                         "without --model and --lobes")
    if args.model == "auto":
        from .select import DEFAULT_CANDIDATES

        _check_fixed(_parse_fixed(args.fixed), DEFAULT_CANDIDATES)
        selection = select(measurements, DEFAULT_CANDIDATES, criterion="auto", target=args.target,
                           progress=_progress(args), **_fit_options(args))
        result = selection.result
    elif args.lobes is None:
        _check_fixed(_parse_fixed(args.fixed), [args.model])
        result = fit(measurements, args.model, multistart=args.multistart, progress=_progress(args),
                     **_fit_options(args))
    elif args.lobes == "auto":
        candidates = [_with_lobes(args.model, k) for k in range(1, args.max_lobes + 1)]
        _check_fixed(_parse_fixed(args.fixed), candidates)
        selection = select(measurements, candidates, criterion="auto", progress=_progress(args),
                           **_fit_options(args))
        result = selection.result
    else:
        try:
            k = int(args.lobes)
        except ValueError:
            raise UsageError(f"--lobes {args.lobes!r}: give a number of lobes or 'auto'") from None
        _check_fixed(_parse_fixed(args.fixed), [_with_lobes(args.model, k)])
        result = fit(measurements, _with_lobes(args.model, k), multistart=args.multistart, progress=_progress(args),
                     **_fit_options(args))
    final = out
    still_free = None if args.force else lambda: check_still_free(final)  # another fit may have finished first
    with staged_folder(final, check=still_free) as out:  # the new files appear in `final` together, replacing it
        h5 = out / FOLDER.results
        io.save(measurements, h5)
        result.save(h5)
        summary = result.to_dict()
        (out / FOLDER.summary_json).write_text(json.dumps(summary, indent=2) + "\n")
        verdict = selection.verdict() + "\n" if selection is not None else ""
        (out / FOLDER.summary).write_text(verdict + result.summary() + "\n")
        files = [h5, out / FOLDER.summary_json, out / FOLDER.summary]
        posterior_summary = None
        if args.posterior:
            post = _run_posterior(result, measurements, h5, args)
            posterior_summary = post.to_dict()
            (out / FOLDER.posterior).write_text(json.dumps(posterior_summary, indent=2) + "\n")
            files.append(out / FOLDER.posterior)
        if selection is not None:
            (out / FOLDER.selection).write_text(json.dumps(selection.to_dict(), indent=2) + "\n")
            files.append(out / FOLDER.selection)
        if args.report:
            written = _write_report(out, measurements, result, post if args.posterior else None, selection, args,
                                    worker=worker)
            files.extend([Path(written["html"]), Path(written["md"])])
    files = [str(final / f.name) for f in files]
    if args.json:
        print(json.dumps({"model": summary["model"], "params": summary["params"], "stderr": summary["stderr"],
                          "posterior": posterior_summary, "metrics": summary["metrics"], "status": summary["status"],
                          "files": files}))
    elif not args.quiet:
        if selection is not None:
            print(selection.verdict())
            print(selection.summary())
        print(result.summary())
        if posterior_summary is not None:
            print(post.table())
        print(f"wrote {', '.join(files)}")
    if not result.plausibility().ok:
        print(f"brdffit fit: warning: the chosen fit {result.spec} is IMPLAUSIBLE (its summary says why); "
              "`brdffit export` refuses it for a renderer unless --force", file=sys.stderr)
    return EXIT_OK if result.converged else EXIT_NOT_CONVERGED


def _engine_loaded(job: str | None = None) -> None:
    """What a command does once the engine's modules are imported: JAX's persistent compilation cache on
    (`enable_compilation_cache`; with ``job``, the programs of the last process with that job read in the background),
    and, in the console script's own process (`run`), every object created so far (the modules of JAX, NumPy,
    brdffit: a few hundred thousand) moved out of the cyclic garbage collector's reach (`gc.freeze`), so that a
    collection traverses only what the command allocates. A caller's process that calls `main` keeps its collector as
    it is: objects frozen there would never be collected."""
    enable_compilation_cache(job)
    if _own_process:
        gc.freeze()


def _import_in_background(module: str) -> None:
    """Import ``module`` in a daemon thread: the report's plotting modules (matplotlib, about half a second) load
    while the fit runs, mostly in XLA's compiled code without Python's lock; a later import of the same module
    waits for this one and then finds it loaded."""
    import importlib
    import threading

    threading.Thread(target=importlib.import_module, args=(module,), name=f"import {module}", daemon=True).start()


def _write_report(out: Path, measurements, result, post, selection, args, exports=None, worker=None) -> dict:
    """The report (report.html, report.md and figures) of a fit in ``out``, with the exports recorded for it."""
    from .report import write_report

    run_info = {"command": "brdffit " + " ".join(sys.argv[1:]) if sys.argv[1:] else "brdffit", "seed": args.seed}
    return write_report(out, measurements, result, posterior=post, selection=selection, run_info=run_info,
                        exports=exports, worker=worker)


def _drawing_worker():
    """In the console script's own process (`run`), a `brdffit.report.worker.DrawingWorker` started now, whose
    imports run beside the fit and which then draws part of the report's figures on the other core; None in a
    caller's process that calls `main` (a test suite's, say), where the report is drawn in that process."""
    if not _own_process:
        return None
    from .report.worker import DrawingWorker

    return DrawingWorker.start()


def _warn(args, message: str) -> None:
    """A problem that did not stop the command, on stderr (also under --quiet)."""
    print(f"brdffit {args.command}: warning: {message}", file=sys.stderr)


def _cmd_report(args) -> int:
    worker = _drawing_worker()  # its imports run while this process reads the results file
    try:
        return _report(args, worker)
    finally:
        if worker is not None:
            worker.close()


def _report(args, worker) -> int:
    """`_cmd_report` (``worker``: a `brdffit.report.worker.DrawingWorker` or None)."""
    import h5py

    from . import FitResult, io
    from .export import records
    from .posterior import load_posterior

    h5 = Path(args.result)
    measurements = io.load(h5)
    result = FitResult.load(h5, args.name)
    _engine_loaded(_job(args, measurements))  # the figures' programs, as a fit's report finds them
    post = None
    with h5py.File(h5, "r") as f:
        chain_group = f"posteriors/{(args.name or result.spec).replace('/', '_')}/chain"
        has_chain = chain_group in f
    if has_chain:
        post = load_posterior(result, measurements, h5, name=args.name)
    exports = records.read(h5)
    if exports.problem:
        _warn(args, f"{exports.problem}; the report does not show the exports recorded there")
    out = Path(args.out) if args.out else h5.parent
    written = _write_report(out, measurements, result, post, None, args, exports, worker=worker)
    if not args.quiet:
        print(f"wrote {written['html']}, {written['md']} and {len(written['figures'])} figures")
    return EXIT_OK


def _run_posterior(result, measurements, h5: Path, args):
    """Sample the posterior of a fit into the results file (resumable) and save its summary there."""
    from . import posterior

    post = posterior(result, measurements, nwalkers=args.walkers, nsteps=args.steps, store=h5,
                     max_samples=args.max_samples, progress=_progress(args), seed=args.seed)
    post.save(h5)
    return post


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM (what ``kill`` and batch systems send) stops the command as Ctrl-C does: it raises
    `brdffit.posterior.Interrupted` (a KeyboardInterrupt), and while a chain samples it stops after the step in
    progress (`brdffit.posterior.posterior`); `main` says so in one line and exits `EXIT_TERMINATED`. Where SIGTERM
    is not at its default (ignored, or the handler of a program that calls `main`), or outside the main thread,
    nothing changes."""
    from .posterior import raise_interrupted

    try:
        taken = signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        if taken:
            signal.signal(signal.SIGTERM, raise_interrupted)
    except ValueError:  # signal.signal outside the main thread
        taken = False
    try:
        yield
    finally:
        if taken:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _cmd_posterior(args) -> int:
    from . import FitResult, io

    with _terminate_as_interrupt():
        _engine_loaded()
        h5 = Path(args.result)
        measurements = io.load(h5)
        result = FitResult.load(h5, args.name)
        post = _run_posterior(result, measurements, h5, args)
    if args.json:
        print(json.dumps(post.to_dict()))
    elif not args.quiet:
        print(post.table())
    return EXIT_OK


def _cmd_synth(args) -> int:
    from . import io, models, synth

    values = _parse_fixed(args.param)
    model = models.get(args.model, channels=args.channels, **values)
    _engine_loaded()
    m = synth.generate(model, pattern=args.pattern, n=args.n, noise=args.noise, seed=args.seed)
    io.save(m, args.out)
    if not args.quiet:
        print(f"wrote {args.out}: {m.n} samples of {model.spec} ({args.pattern}, noise {args.noise or 'none'})")
    return EXIT_OK


def _cmd_convert(args) -> int:
    from . import io

    source, target = Path(args.input), Path(args.output)
    if target.suffix.lower() in (".binary", ".merl"):
        from . import FitResult

        # A MERL table is a tabulation of a model: take the fit stored in a results file.
        try:
            result = FitResult.load(source, args.name)
        except (OSError, io.FormatError) as exc:
            raise UsageError(f"{source}: a MERL file is written by tabulating a model; give a results file with a "
                             f"fit (from `brdffit fit`), not raw measurements ({exc})") from None
        if result.model is None or result.model.channels != 3:
            raise UsageError(f"{source}: MERL tables hold 3 channels; this fit has "
                             f"{'independent channels' if result.model is None else result.model.channels}")
        _engine_loaded()
        io.write_merl(result.model, target)
        if not args.quiet:
            print(f"wrote {target}: MERL tabulation of {result.spec}")
        return EXIT_OK
    m = _load(source, args)
    io.save(m, target)
    if not args.quiet:
        print(f"wrote {target}: {m.n} samples x {m.n_channels} channels")
    return EXIT_OK


def _cmd_export(args) -> int:
    from . import FitResult
    from .export import TARGETS, export, export_details

    result = FitResult.load(args.result, args.name)
    if TARGETS[args.to].renderer and not args.force and not result.plausibility().ok:
        why = "; ".join(c.message for c in result.plausibility().implausible)
        print(f"brdffit export: {args.result}: the fit {result.spec} is IMPLAUSIBLE ({why}); a renderer would show "
              "a material that reflects more light than it receives. Refit with another model, or give --force to "
              "export it anyway", file=sys.stderr)
        return EXIT_IMPLAUSIBLE
    _engine_loaded()
    # A spectral fit is written for a renderer as its RGB model (brdffit.colour.rgb_model).
    wavelengths = _stored_wavelengths(args.result, result.model.channels) \
        if TARGETS[args.to].renderer and result.model is not None else None
    # The fit option's export to a renderer is recorded beside the result, for its report.
    recorded = args.fit and TARGETS[args.to].renderer
    details = export_details(result, args.to, name=args.material, fit=True, wavelengths=wavelengths) \
        if recorded else None
    text = details.text if recorded else export(result, to=args.to, name=args.material, fit=args.fit,
                                                wavelengths=wavelengths)
    if args.out:
        from .io._common import atomic_path

        with atomic_path(args.out) as tmp:
            Path(tmp).write_text(text if text.endswith("\n") else text + "\n")
        if not args.quiet:
            print(f"wrote {args.out}")
    else:
        print(text)
    if recorded:
        _record_export(args, details)
    return EXIT_OK


def _record_export(args, details) -> None:
    """Record a fit-option export in the exports.json of the result's output folder, if it has one; an existing
    file that cannot be read (or a folder that cannot be written) is left as it is, with a warning."""
    from .export import records
    from .io import FormatError

    try:
        path = records.record(args.result, details, args.to, out=args.out)
    except (FormatError, OSError) as exc:
        _warn(args, f"{exc}; this export was not recorded (exports.json is left as it is)")
        return
    if path is not None and not args.quiet:
        # stdout holds the material when no --out is given
        print(f"recorded its achieved error in {path} (for the report)", file=sys.stdout if args.out else sys.stderr)


def _render_source(path: Path, args):
    """What `brdffit render` shades: a MERL table, the fit stored in a results file, or the measurements (read
    with the table options when given); with the wavelengths of spectral channels (None otherwise)."""
    import h5py

    from . import FitResult, io

    use_data, name = args.data, args.name
    if _table_options(args):
        m = _load(path, args)
        return m, "measurements (interpolated)", _wavelengths(m, len(m.channels), path)
    if io.detect_format(path) == "merl":
        return io.read_merl(path), "MERL table", None
    if not use_data and io.detect_format(path) == "hdf5":
        with h5py.File(path, "r") as f:
            has_fit = "fits" in f and len(f["fits"]) > 0
        if has_fit:
            result = FitResult.load(path, name)
            if result.model is None:
                raise UsageError(f"{path}: the fit has independent channels; render one channel's model instead")
            return result.model, f"fit {result.spec}", _stored_wavelengths(path, result.model.channels)
    m = _load(path, args)
    return m, "measurements (interpolated)", _wavelengths(m, len(m.channels), path)


def _wavelengths(measurements, channels: int, path) -> list | None:
    """The wavelengths of spectral channels in the measurements' metadata (ASTM E1392 bands), or None."""
    from .colour import wavelengths_of

    return wavelengths_of(measurements.meta, channels, str(path))


def _stored_wavelengths(path, channels: int) -> list | None:
    """The wavelengths of a fit's spectral channels, from the measurements `brdffit fit` stores beside it in the
    results file (None where the file has none, or they are not spectral)."""
    from .colour import wavelengths_of
    from .io import FormatError
    from .io.hdf5 import read_meta

    try:
        meta = read_meta(path)
    except FormatError:  # a results file written by FitResult.save alone has no /measurements
        return None
    return wavelengths_of(meta, channels, str(path))


def _cmd_render(args) -> int:
    from . import render

    path = Path(args.file)
    source, what, wavelengths = _render_source(path, args)
    _engine_loaded()
    lights = list(render.DEFAULT_LIGHTS)
    if args.area_light:
        key_theta, key_phi, key_intensity = lights[0]
        lights = render.area_light(key_theta, key_phi, key_intensity, args.area_light, samples=16) + lights[1:]
    if args.plane:
        hdr = render.render_plane(source, lights, resolution=args.resolution, isotropic=not args.anisotropic,
                                  distance=render.PLANE_VIEW_DISTANCE)  # at infinity it would be one flat colour
        what += f", a plane seen from distance {render.PLANE_VIEW_DISTANCE:g} (side 2)"
    else:
        hdr = render.render_sphere(source, lights, resolution=args.resolution, isotropic=not args.anisotropic)
    if wavelengths is not None:  # the spectral radiance as linear sRGB under D65 (brdffit.colour)
        from .colour import ColourError, spectral_colour

        try:
            hdr = spectral_colour(wavelengths, f"{path}: wavelengths").linear_srgb(hdr)
            what += f", its {len(wavelengths)} bands shown in sRGB (CIE 1931 XYZ under D65)"
        except ColourError as exc:  # bands the eye does not see (infrared, say): their mean, in grey
            hdr = hdr.mean(axis=-1, keepdims=True)
            what += f", shown in grey as the mean of its bands ({exc})"
    out = Path(args.out) if args.out else path.with_suffix(".png")
    render.save_png(out, render.tonemap(hdr, args.tonemap, args.exposure))
    written = [str(out)]
    if args.npy:
        render.save_npy(out.with_suffix(".npy"), hdr)
        written.append(str(out.with_suffix(".npy")))
    if not args.quiet:
        print(f"rendered {what} from {path}: wrote {', '.join(written)}")
    return EXIT_OK


def _add_posterior_options(p):
    p.add_argument("--walkers", type=bounded(int, 2), default=POSTERIOR.walkers,
                   help=f"emcee walkers (default {POSTERIOR.walkers})")
    p.add_argument("--steps", type=bounded(int, 1), default=POSTERIOR.steps,
                   help=f"steps per walker in total (default {POSTERIOR.steps})")
    p.add_argument("--max-samples", type=bounded(int, 1), default=None, metavar="N",
                   help="run the chain on a stratified subsample of N samples")


def _cmd_select(args) -> int:
    measurements = _load(args.file, args)  # first: a file that cannot be read is reported before JAX is loaded
    from . import select
    from .select import DEFAULT_CANDIDATES

    _engine_loaded(_job(args, measurements))
    candidates = [c.strip() for c in args.candidates.split(";")] if args.candidates else list(DEFAULT_CANDIDATES)
    _check_fixed(_parse_fixed(args.fixed), candidates)
    selection = select(measurements, candidates, criterion=args.criterion, folds=args.folds,
                       progress=_progress(args), **_fit_options(args))
    if args.json:
        print(json.dumps(selection.to_dict()))
    else:
        print(selection.summary())
    return EXIT_OK


def _cmd_batch(args) -> int:
    if args.scheduler and args.workers is not None:
        raise UsageError("--workers sizes the local cluster; a --scheduler cluster has its own workers")
    from .distributed.table import table_format

    try:
        table_format(args.out)
    except (ValueError, ImportError) as exc:
        raise UsageError(f"--out: {exc}") from None
    from collections import Counter

    from distributed import Client

    from . import fit_database

    from .select import DEFAULT_CANDIDATES

    _check_fixed(_parse_fixed(args.fixed), DEFAULT_CANDIDATES if args.model == "auto" else [args.model])
    _engine_loaded()
    client = None
    if args.scheduler:
        try:
            client = Client(args.scheduler, timeout="20s")
        except (OSError, ValueError) as exc:
            raise UsageError(f"--scheduler {args.scheduler}: cannot connect ({exc})") from None
    try:
        rows = fit_database(args.sources, args.model, client=client, batch=args.batch, out=args.out,
                            resume=args.resume, workers=args.workers, read_options=_table_options(args) or None,
                            cache_dir=cache_dir(), progress=_progress(args), **_fit_options(args))
    finally:
        if client is not None:
            client.close()
    counts = Counter(row["status"] for row in rows)
    if args.json:
        print(json.dumps({"out": str(args.out), "materials": len(rows), "statuses": dict(counts)}))
    elif not args.quiet:
        print(f"{len(rows)} materials: {', '.join(f'{n} {status}' for status, n in counts.most_common())}; "
              f"wrote {args.out}")
    from .fitting.outcome import STATUSES, Status

    # a failed material's row has the status "error"
    converged = all(row["status"] in STATUSES and Status(row["status"]).converged for row in rows)
    return EXIT_OK if converged else EXIT_NOT_CONVERGED


def _add_fit_options(p):
    from .fitting.losses import LOSSES
    from .fitting.solvers import SOLVERS

    p.add_argument("--loss", default=FIT.loss, choices=list(LOSSES),
                   help=f"residual definition (default {FIT.loss}): " + "; ".join(f"{name}: {loss.formula}"
                                                                          for name, loss in LOSSES.items()))
    p.add_argument("--solver", default=FIT.solver, choices=list(SOLVERS),
                   help=f"least-squares solver (default {FIT.solver})")
    p.add_argument("--fixed", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value (repeatable; a colour takes R,G,B)")
    p.add_argument("--seed", type=bounded(int, 0), default=FIT.seed,
                   help=f"seed of subsamples and starts (default {FIT.seed})")
    p.add_argument("--max-steps", type=bounded(int, 1), default=FIT.max_steps, metavar="N",
                   help=f"solver step limit (default {FIT.max_steps})")


def _add(sub, name, help_text, examples, run):
    p = sub.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:] + ".",
                       epilog="Examples:\n  " + "\n  ".join(examples),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.set_defaults(run=run)
    return p


MEASUREMENT_FILE = ("measurement file in any format brdffit.io.load reads (docs/formats.md): brdffit .h5, MERL "
                    ".binary, a table (.csv/.tsv/text; see the table options), ...")
PTFE_EXAMPLE = ("../shared/data/nist-ptfe/PTFE.data.csv --columns theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir "
                "--values f_r11")


def _models_command(sub) -> None:
    """The ``brdffit models`` command's arguments."""
    _add(sub, "models", "list every lobe with its parameters, bounds and reference", ["brdffit models"],
         _cmd_models)


def _info_command(sub) -> None:
    """The ``brdffit info`` command's arguments."""
    p = _add(sub, "info", "describe the measurements in a file",
             ["brdffit info data/synthetic/plastic.h5", "brdffit info table.csv --json",
              f"brdffit info {PTFE_EXAMPLE} --where lambda=0.532"], _cmd_info)
    p.add_argument("file", help=MEASUREMENT_FILE)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_table_options(p)


def _fit_command(sub) -> None:
    """The ``brdffit fit`` command's arguments."""
    p = _add(sub, "fit", "fit a model to the measurements in a file and write the result",
             ["brdffit fit data/synthetic/plastic.h5",
              "brdffit fit data/synthetic/plastic.h5 --model lambert+ggx --fixed f0=0.04 --out out/",
              "brdffit fit data/synthetic/clay.h5 --model oren-nayar --json",
              f"brdffit fit {PTFE_EXAMPLE} --where lambda=0.532 --model lambert --out ptfe/"], _cmd_fit)
    p.add_argument("file", help=MEASUREMENT_FILE)
    p.add_argument("--model", default=DEFAULT_MODEL,
                   help="model spec, lobes joined with '+' (see `brdffit models`), or 'auto' (the default): "
                        "choose among the standard candidates by the 'auto' criterion: BIC where the data state "
                        "sigma, else the error on held-out directions (`brdffit select`)")
    p.add_argument("--lobes", metavar="K|auto",
                   help="number of Lafortune lobes in the model's Lafortune term, or 'auto' to choose 1.."
                        "--max-lobes by the 'auto' criterion")
    p.add_argument("--max-lobes", type=bounded(int, 1), default=3, metavar="K", help="largest K tried by --lobes auto")
    from .export.registry import FIT_TARGETS, TARGETS

    p.add_argument("--for", dest="target", choices=FIT_TARGETS, metavar="TARGET",
                   help="fit for a renderer: choose among the models it represents exactly with every parameter in "
                        "its ranges (" + "; ".join(f"{t}: {', '.join(TARGETS[t].renders)}" for t in FIT_TARGETS)
                        + "), and state the held-out error of the best model without its limits beside it")
    _add_fit_options(p)
    p.add_argument("--multistart", type=bounded(int, 0), default=0, metavar="N", help="extra quasi-random starts")
    p.add_argument("--posterior", action="store_true",
                   help="also sample the parameter posterior with emcee (stored in result.h5, resumable)")
    p.add_argument("--no-report", dest="report", action="store_false",
                   help="skip report.html / report.md and their figures")
    _add_posterior_options(p)
    p.add_argument("--out", help="output folder (default: next to the input, <name>.brdffit/)")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier result in the output folder (without it, such a folder is refused)")
    p.add_argument("--json", action="store_true", help="print one machine-readable JSON summary to stdout")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    _add_table_options(p)


def _posterior_command(sub) -> None:
    """The ``brdffit posterior`` command's arguments."""
    p = _add(sub, "posterior", "sample (or resume) the parameter posterior of a fit stored in a results file",
             ["brdffit posterior data/synthetic/plastic.brdffit/result.h5",
              "brdffit posterior out/result.h5 --steps 10000   # continues a stored chain"], _cmd_posterior)
    p.add_argument("result", help="results file written by `brdffit fit` (result.h5)")
    p.add_argument("--name", help="which fit in the file (default: the first)")
    _add_posterior_options(p)
    p.add_argument("--seed", type=bounded(int, 0), default=POSTERIOR.seed,
                   help=f"seed of the walkers' start (default {POSTERIOR.seed})")
    p.add_argument("--json", action="store_true", help="print the posterior summary as JSON")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


def _report_command(sub) -> None:
    """The ``brdffit report`` command's arguments."""
    p = _add(sub, "report", "write report.html and report.md (with figures) for a fit stored in a results file",
             ["brdffit report data/synthetic/plastic.brdffit/result.h5",
              "brdffit report out/result.h5 --out report-folder/"], _cmd_report)
    p.add_argument("result", help="results file written by `brdffit fit` (result.h5)")
    p.add_argument("--name", help="which fit in the file (default: the first)")
    p.add_argument("--out", help="output folder (default: the results file's folder)")
    p.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


def _synth_command(sub) -> None:
    """The ``brdffit synth`` command's arguments."""
    p = _add(sub, "synth", "write synthetic measurements of a model",
             ["brdffit synth lambert+ggx --param alpha=0.2 --pattern half-diff --n 2000 --noise relative:0.01 "
              "--out ggx.h5"], _cmd_synth)
    p.add_argument("model", help="model spec")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value (repeatable)")
    p.add_argument("--channels", type=bounded(int, 1), default=3, help="number of channels (default 3)")
    p.add_argument("--pattern", default="uniform", choices=RegistryNames("brdffit.synth", "PATTERNS"),
                   metavar="NAME", help="sampling pattern: %(choices)s (default %(default)s)")
    p.add_argument("--n", type=bounded(int, 1), default=None, help="number of samples")
    p.add_argument("--noise", default=None, help="noise spec, e.g. relative:0.01 or gaussian:0.002")
    p.add_argument("--seed", type=bounded(int, 0), default=0, help="seed (default 0)")
    p.add_argument("--out", required=True, help="output file (.h5 or .csv)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


def _convert_command(sub) -> None:
    """The ``brdffit convert`` command's arguments."""
    p = _add(sub, "convert", "convert measurements between CSV and HDF5, or tabulate a fit as a MERL file",
             ["brdffit convert table.csv table.h5", "brdffit convert out/result.h5 fitted.binary"], _cmd_convert)
    p.add_argument("input", help=MEASUREMENT_FILE + "; for a .binary output, a results file with a fit")
    p.add_argument("output", help="output file (.csv, .h5, or .binary for a MERL tabulation of a fit)")
    p.add_argument("--name", help="which fit of a results file to tabulate (default: the first)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    _add_table_options(p)


def _export_command(sub) -> None:
    """The ``brdffit export`` command's arguments."""
    p = _add(sub, "export", "write a fitted material in the form a renderer takes (json, Mitsuba 3 XML, pbrt-v4)",
             ["brdffit export data/synthetic/plastic.brdffit/result.h5 --to mitsuba",
              "brdffit export out/result.h5 --to pbrt --out material.pbrt"], _cmd_export)
    p.add_argument("result", help="results file written by `brdffit fit` (result.h5)")
    from .export import TARGETS

    p.add_argument("--to", required=True, choices=list(TARGETS), help="target format: " + "; ".join(
        f"{t.name}: {t.description}" for t in TARGETS.values()))
    p.add_argument("--fit", action="store_true", help="renderers: fit the renderer's own model to the fitted one "
                   "(cosine-weighted least squares) and write the closest, with the achieved error; also exports "
                   "lobes with no equivalent (docs/export.md)")
    p.add_argument("--name", help="which fit in the file (default: the first)")
    p.add_argument("--material", default="material", help="material name in the output (default 'material')")
    p.add_argument("--out", help="output file (default: print to stdout)")
    p.add_argument("--force", action="store_true",
                   help="export a renderer material of an IMPLAUSIBLE fit (refused otherwise, exit "
                        f"{EXIT_IMPLAUSIBLE})")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


def _render_command(sub) -> None:
    """The ``brdffit render`` command's arguments."""
    p = _add(sub, "render", "render a sphere (or plane) preview of a fit, a MERL table or measured data",
             ["brdffit render data/synthetic/plastic.brdffit/result.h5 --out plastic.png",
              "brdffit render data/synthetic/plastic.h5 --tonemap filmic --npy   # the measured data, interpolated",
              "brdffit render material.binary --plane"], _cmd_render)
    p.add_argument("file", help="a results file (renders its fit), measurements (.h5/.csv) or a MERL .binary")
    p.add_argument("--data", action="store_true", help="render the measurements even if the file holds a fit")
    p.add_argument("--name", help="which fit of a results file (default: the first)")
    p.add_argument("--plane", action="store_true",
                   help="a flat square swatch (side 2) seen from distance 3 instead of a sphere, so that the "
                        "highlight moves across it (a viewer at infinity would see one flat colour)")
    p.add_argument("--resolution", type=bounded(int, 8, 4096), default=256, help="image size in pixels (default 256)")
    p.add_argument("--tonemap", default="reinhard", choices=RegistryNames("brdffit.render", "TONEMAPS"),
                   metavar="NAME", help="tone curve before sRGB encoding: %(choices)s (default %(default)s)")
    p.add_argument("--exposure", type=bounded(float, 0.0), default=1.0, help="exposure multiplier (default 1)")
    p.add_argument("--area-light", type=bounded(float, 0.0, 1.5), default=0.0, metavar="RADIUS",
                   help="make the key light an area light of this angular radius (radians), 16 samples")
    p.add_argument("--anisotropic", action="store_true", help="interpolate measured data as anisotropic")
    p.add_argument("--npy", action="store_true", help="also write the HDR image as float32 .npy (linear sRGB for "
                   "spectral data)")
    p.add_argument("--out", help="PNG path (default: the input with .png)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    _add_table_options(p)


def _select_command(sub) -> None:
    """The ``brdffit select`` command's arguments."""
    p = _add(sub, "select", "fit candidate models and choose the smallest that is good enough",
             ["brdffit select data/synthetic/plastic.h5",
              "brdffit select data/synthetic/lafortune-retro.h5 --candidates "
              "'lambert+lafortune;lambert+lafortune(lobes=2)' --criterion cv"], _cmd_select)
    p.add_argument("file", help=MEASUREMENT_FILE)
    p.add_argument("--candidates", help="model specs separated by ';' (default: the standard candidate list)")
    p.add_argument("--criterion", default="auto", choices=CRITERIA,
                   help=f"selection criterion: {', '.join(CRITERIA)} (default auto: bic where the data state their "
                        "σ, else heldout)")
    p.add_argument("--folds", type=bounded(int, 2), default=5, help="folds of --criterion cv (default 5)")
    _add_fit_options(p)
    p.add_argument("--json", action="store_true", help="print the selection as one JSON object")
    _add_table_options(p)


def _batch_command(sub) -> None:
    """The ``brdffit batch`` command's arguments."""
    p = _add(sub, "batch", "fit every material of a database on a Dask cluster into one results table",
             ["brdffit batch 'merl/*.binary' --model lambert+ggx --out merl.h5",
              "brdffit batch textures.h5 --model lambert+ggx --out texels.parquet --scheduler tcp://host:8786",
              "brdffit batch scans/ --model auto --out scans.csv --workers 2   # reruns complete a table"],
             _cmd_batch)
    p.add_argument("sources", nargs="+", metavar="PATH_OR_GLOB",
                   help="measurement files (any format brdffit reads), folders, globs, multi-material brdffit HDF5 "
                        "files (every material group) or FILE.h5::GROUP")
    p.add_argument("--model", default=DEFAULT_MODEL,
                   help="model spec fitted to every material, or 'auto' (the default): a selection by BIC among "
                        "the standard candidates per material (slow)")
    p.add_argument("--out", required=True, help="results table: .h5, .csv or .parquet (needs pyarrow)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://HOST:8786, started with `dask scheduler` and `dask worker`); "
                        "default: a local cluster on this machine's cores")
    p.add_argument("--workers", type=bounded(int, 1), metavar="N",
                   help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--batch", type=bounded(int, 1), default=DEFAULT_BATCH, metavar="N",
                   help=f"the most materials one task reads and fits (default {DEFAULT_BATCH})")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="keep the rows of --out and fit only the other materials and the failed ones (the default); "
                        "--no-resume starts a new table")
    _add_fit_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object: out, materials, statuses")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    _add_table_options(p)


# Each command's arguments, in the order `brdffit --help` lists the commands.
COMMANDS = (_models_command, _info_command, _fit_command, _posterior_command, _report_command, _synth_command,
            _convert_command, _export_command, _render_command, _select_command, _batch_command)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every ``brdffit`` command."""
    parser = argparse.ArgumentParser(
        prog="brdffit",
        description="Fit analytic BRDF models to measured reflectance.",
        epilog="Examples:\n  brdffit fit data/synthetic/plastic.h5\n  brdffit info data/synthetic/plastic.h5\n"
               "  brdffit models",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"brdffit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``brdffit`` console script; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on usage errors and 0 on --help/--version
        return int(exc.code or 0)
    if not getattr(args, "run", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return args.run(args)
    # brdffit.io.FormatError and brdffit.MeasurementError are ValueErrors: naming them would load the readers and
    # NumPy for every command, the light ones too (`brdffit models`).
    except (UsageError, OutputFolderError, FileNotFoundError, IsADirectoryError, KeyError, ValueError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"brdffit {args.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:  # one line naming the limit that was reached (ulimit -v), never a traceback
        from .io._common import out_of_memory

        print(f"brdffit {args.command}: error: {out_of_memory()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:  # one line, no traceback; what was kept is said by the exception, if anything
        # `fit` writes its folder as a whole (staged_folder): an interrupted fit leaves the earlier folder as it was.
        kept = "nothing was written; the output folder is as it was" if args.command == "fit" else str(exc)
        print(f"brdffit {args.command}: interrupted{': ' + kept if kept else ''}", file=sys.stderr)
        return EXIT_TERMINATED if getattr(exc, "signum", signal.SIGINT) == signal.SIGTERM else EXIT_INTERRUPTED


def run() -> None:
    """The ``brdffit`` console script: `main`, then the process ends without Python's finalisation.

    After a fit, finalisation frees the objects of JAX, XLA, SciPy and matplotlib one by one: about half a second
    of a warm default fit's wall time on the 2-core host (docs/benchmarks.md), spent after the last line is
    written. The exit handlers still run (`atexit`: logging, a Dask cluster's processes, JAX's backend) and the
    standard streams are flushed; a process with a non-daemon thread still running exits the usual way.

    The process is the command's own, so its cyclic garbage collector runs less often (`COLLECTOR_THRESHOLDS`) and
    skips the objects of the imports (`_engine_loaded`), and its malloc keeps freed memory for the next pass
    (`brdffit._memory.keep_freed_memory`)."""
    global _own_process
    _own_process = True
    keep_freed_memory()
    gc.set_threshold(*COLLECTOR_THRESHOLDS)
    code = main()
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        sys.exit(code)
    atexit._run_exitfuncs()  # the handlers that sys.exit would run (the atexit module's own, private, since 3.0)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:  # a reader that went away (brdffit models | head): nothing more can be written
        pass
    os._exit(code)


if __name__ == "__main__":
    run()
