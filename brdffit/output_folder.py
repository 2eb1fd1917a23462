"""The output folder of `brdffit fit`: what it holds, and writing it as a whole.

`FOLDER` names every file a fit writes there (and the one `brdffit export --fit` adds), once: the CLI writes and
checks them, the export records find a result by them. `staged_folder` writes a new result beside the folder and
exchanges the two in one atomic rename, so that the folder holds either the complete earlier result or the complete
new one at every moment (docs/cli.md).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from pathlib import Path

__all__ = ["FOLDER", "FitFolder", "OutputFolderError", "STAGE_MARK", "check_output_folder", "check_still_free",
           "check_writable", "default_out", "staged_folder"]


class OutputFolderError(Exception):
    """An output folder that cannot take a result (not writable, holding others' files or an earlier result)."""


@dataclasses.dataclass(frozen=True)
class FitFolder:
    """The files of a fit's output folder; the report's figures are PNG files beside ``report.html``.

    Attributes:
        results: the measurements and the fit (`brdffit.FitResult.save`).
        summary_json: the fit's summary as JSON (`FitResult.to_dict`).
        summary: the verdict and the fit's summary as text.
        posterior: the posterior's summary (with ``--posterior``).
        selection: the model selection's table (when the model was chosen).
        report_html, report_md: the report (`brdffit.report.write_report`).
        exports: the exports recorded under ``brdffit export --fit`` (`brdffit.export.records`).
    """

    results: str = "result.h5"
    summary_json: str = "result.json"
    summary: str = "summary.txt"
    posterior: str = "posterior.json"
    selection: str = "selection.json"
    report_html: str = "report.html"
    report_md: str = "report.md"
    exports: str = "exports.json"

    def names(self) -> tuple[str, ...]:
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self))

    def holds(self, name: str) -> bool:
        """Whether ``name`` is a file brdffit writes into such a folder (one of `names`, or a figure)."""
        return name in self.names() or name.endswith(".png")


FOLDER = FitFolder()


def default_out(path: Path) -> Path:
    """The output folder of a fit of ``path`` when none is given: ``<name>.brdffit`` beside it."""
    return path.with_name(path.stem + ".brdffit")


def check_writable(out: Path) -> None:
    """Refuse, before any work, an output folder that cannot be made (e.g. the default beside a read-only input)."""
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise OutputFolderError(f"cannot write the output folder {out} ({existing} is not a writable folder); "
                                "choose one with --out")


STAGE_MARK = ".new-"  # a folder being written: .<out name>.new-<pid>-<random> beside the output folder


def _earlier_result(out: Path) -> list[str]:
    """The names in ``out`` (an earlier result); raises OutputFolderError if any of them is not brdffit's output."""
    if not out.is_dir():
        return []
    names = sorted(os.listdir(out))
    foreign = [n for n in names if not FOLDER.holds(n)]
    if foreign:
        raise OutputFolderError(f"the output folder {out} holds files brdffit did not write ({', '.join(foreign[:5])}); "
                                "choose another --out")
    return names


def check_output_folder(out: Path, force: bool) -> None:
    """Refuse, before any work, to replace an earlier result without ``--force`` (it would lose that fit)."""
    earlier = _earlier_result(out)
    if earlier and not force:
        raise OutputFolderError(f"the output folder {out} holds an earlier result ({', '.join(earlier[:4])}"
                                f"{', ...' if len(earlier) > 4 else ''}); pass --force to replace it, or choose "
                                "another --out")


def check_still_free(out: Path) -> None:
    """Refuse, at the end of a fit without --force, a result that another process wrote into ``out`` meanwhile."""
    earlier = _earlier_result(out)
    if earlier:
        raise OutputFolderError(f"while this fit ran, another process wrote a result into {out} ({', '.join(earlier[:4])}"
                                f"{', ...' if len(earlier) > 4 else ''}); this fit's result was not written: pass "
                                "--force to replace that one, or choose another --out")


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux renameat2 with RENAME_EXCHANGE); False where it is unavailable."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2  # <fcntl.h> AT_FDCWD, <linux/fs.h> RENAME_EXCHANGE
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


def _remove_abandoned(out: Path) -> None:
    """Delete the staging folders beside ``out`` of earlier runs that were killed (their process is gone)."""
    import functools
    import shutil

    from .io._common import remove_abandoned

    remove_abandoned(out.parent, f".{out.name}{STAGE_MARK}", functools.partial(shutil.rmtree, ignore_errors=True))


@contextlib.contextmanager
def staged_folder(out: Path, check=None):
    """Yield a new, empty folder beside ``out`` to write a result into; on success it takes ``out``'s place.

    The folder holds either the complete earlier result or the complete new one at every moment: the new files are
    written under the staging name, and the staging folder and ``out`` are exchanged in one atomic rename
    (renameat2 RENAME_EXCHANGE; where the system lacks it, two renames leave a moment without ``out``); the earlier
    result is deleted only then. On failure the staging folder is deleted and ``out`` is untouched. A staging
    folder left by a killed run (``.<name>.new-<pid>-*``) is deleted by the next run.

    The exchange holds the lock of ``out``'s parent folder (`brdffit.io.locking.locked`), so that two processes
    finishing into one folder take turns; ``check``, when given, runs under that lock just before it (a fit
    without --force refuses there a result that another process wrote into ``out`` while it ran).
    """
    import shutil
    import tempfile

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_abandoned(out)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}{STAGE_MARK}{os.getpid()}-", dir=out.parent))
    umask = os.umask(0o022)
    os.umask(umask)
    try:
        os.chmod(stage, 0o777 & ~umask)  # what mkdir would have given the folder (mkdtemp makes it private)
        yield stage
        from .io.locking import locked

        with locked(out):
            if check is not None:
                check()
            _commit(stage, out)
    finally:
        shutil.rmtree(stage, ignore_errors=True)  # after an exchange it holds the earlier result


def _commit(stage: Path, out: Path) -> None:
    """Put the complete folder ``stage`` in ``out``'s place (`staged_folder`)."""
    import shutil
    import tempfile

    if not out.exists():
        os.rename(stage, out)
    elif not _exchange(stage, out):
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}{STAGE_MARK}{os.getpid()}-", dir=out.parent))
        os.rename(out, old / out.name)
        os.rename(stage, out)
        shutil.rmtree(old, ignore_errors=True)
