"""What a database fit reads: one material per source, a file of any format `brdffit.io.load` reads or one group
of a multi-material brdffit HDF5 file (docs/batch.md).

A multi-material HDF5 file holds several groups in the layout of ``/measurements`` (docs/formats.md), e.g.
``/materials/red`` and ``/materials/blue``, written with `brdffit.io.update_hdf5` and
`brdffit.io.hdf5.write_measurements_group`. A source names one of them as ``FILE::GROUP``; the file alone stands
for all of them (or for its ``/measurements`` group where it has one). Every opening of a brdffit HDF5 file
inspects all of it in a child process (`brdffit.io.hdf5.inspect_hdf5`): the files a task reads are read by the
child that inspects them, one child for the batch (`brdffit.io.hdf5.read_hdf5_many`), each file once.
"""

from __future__ import annotations

import dataclasses
import glob
from pathlib import Path
from typing import NamedTuple

from ..io import FORMATS, FormatError, detect_format, load
from ..io.hdf5 import MEASUREMENTS_GROUP, read_hdf5_many, read_measurements_group
from ..measurements import Measurements

__all__ = ["Source", "Read", "GROUP_SEPARATOR", "expand_sources", "read_sources", "material_groups", "error_text"]

GROUP_SEPARATOR = "::"

# A group holds a material when it has the datasets every /measurements group has (brdffit.io.hdf5).
_MATERIAL_DATASETS = ("theta_i", "phi_i", "theta_o", "phi_o", "values")


@dataclasses.dataclass(frozen=True)
class Source:
    """One material of a database, or a multi-material HDF5 file that stands for its material groups.

    Attributes:
        path: the file, absolute (workers may run in another folder).
        group: the HDF5 group holding the material; None for a file (one material, or a brdffit HDF5 file without
            ``/measurements``, whose material groups `read_sources` lists).
    """

    path: str
    group: str | None = None

    @property
    def key(self) -> str:
        """The source's name in the results table: ``PATH`` or ``PATH::GROUP``."""
        return self.path if self.group is None else f"{self.path}{GROUP_SEPARATOR}{self.group}"


class Read(NamedTuple):
    """What reading a source gave: its measurements, the member sources of a multi-material file, or an error."""

    source: Source
    measurements: Measurements | None = None
    members: tuple = ()
    error: str = ""


def material_groups(f) -> list[str]:
    """The groups of an open brdffit HDF5 file (`brdffit.io.hdf5.open_hdf5`) that hold a material, in file order
    (``/measurements`` first)."""
    found = []
    f.visititems(lambda name, obj: found.append(name) if _holds_material(obj) else None)
    return sorted(found, key=lambda name: name != MEASUREMENTS_GROUP)


def _holds_material(obj) -> bool:
    """Whether an h5py object, or a group's contents as the inspection kept them (`brdffit.io.hdf5.read_hdf5_many`:
    ``members`` name -> dataset, None for a member that is not one), holds a material."""
    members = getattr(obj, "members", None)
    if members is not None:  # no lookup in the file: h5py's high-level objects are costly next to the reading
        return all(members.get(d) is not None for d in _MATERIAL_DATASETS)
    import h5py

    return isinstance(obj, h5py.Group) and all(isinstance(obj.get(d), h5py.Dataset) for d in _MATERIAL_DATASETS)


def _absolute(group: str) -> str:
    """A group's name as the inspection keeps it (``"/measurements"``)."""
    return "/" + group.strip("/")


def error_text(err: BaseException) -> str:
    """The error column's text of an exception: ``"FormatError: <path>: line 3: ..."``."""
    return f"{type(err).__name__}: {err}"


def _read_hdf5(f, path: str, sources: list[Source], captured: dict) -> list[Read]:
    """Read sources of one open brdffit HDF5 file: the named groups, and for the file itself its ``/measurements``
    or the list of its material groups; a group's datasets as the inspection kept them (``captured``: group name
    -> `brdffit.io.hdf5.read_hdf5_many`'s contents)."""
    def group(name: str):
        return captured.get(_absolute(name)) or f[name]

    reads = []
    for source in sources:
        try:
            if source.group is not None:
                if source.group not in f:
                    raise FormatError(path, f"no group /{source.group}")
                reads.append(Read(source, read_measurements_group(group(source.group), path)))
                continue
            # /measurements, where the file has it, is the file's material: no need to visit the others
            own = captured.get(_absolute(MEASUREMENTS_GROUP)) or f.get(MEASUREMENTS_GROUP)
            groups = [MEASUREMENTS_GROUP] if _holds_material(own) else material_groups(f)
            if not groups:
                raise FormatError(path, f"no group holds a material (datasets {', '.join(_MATERIAL_DATASETS)})")
            if groups[0] == MEASUREMENTS_GROUP:
                reads.append(Read(source, read_measurements_group(group(MEASUREMENTS_GROUP), path)))
            else:
                reads.append(Read(source, members=tuple(Source(path, group) for group in groups)))
        except Exception as err:  # noqa: BLE001 - a damaged group is that material's error
            reads.append(Read(source, error=error_text(err)))
    return reads


def read_sources(sources, read_options: dict | None = None) -> list[Read]:
    """Read materials, each failure kept as its own error.

    Arguments:
        sources: `Source` objects.
        read_options: keywords of `brdffit.io.load` for files that are not brdffit HDF5 (table options, MERL
            ``subsample``, ...).

    Returns:
        One `Read` per source, in order.
    """
    sources = list(sources)
    by_file: dict[str, list[Source]] = {}
    reads = {}
    for source in sources:
        try:
            hdf5 = source.group is not None or detect_format(source.path) == "hdf5"
        except Exception as err:  # noqa: BLE001
            reads[source] = Read(source, error=error_text(err))
            continue
        if hdf5:
            by_file.setdefault(source.path, []).append(source)
            continue
        try:
            reads[source] = Read(source, load(source.path, **(read_options or {})))
        except Exception as err:  # noqa: BLE001 - an unreadable material is its row's error
            reads[source] = Read(source, error=error_text(err))
    # Each file read once, by the child that inspects it; the batch's files in one child (brdffit.io.hdf5).
    def capture(path):
        return {_absolute(source.group or MEASUREMENTS_GROUP) for source in by_file[str(path)]}

    def read(f, path, captured):
        return _read_hdf5(f, str(path), by_file[str(path)], captured)

    for path, outcome in read_hdf5_many(by_file, capture, read):
        if isinstance(outcome, Exception):  # every source of the file gets the reason
            reads.update((source, Read(source, error=error_text(outcome))) for source in by_file[str(path)])
        else:
            reads.update((read.source, read) for read in outcome)
    return [reads[source] for source in sources]


def _files(item: str) -> list[Path]:
    """The files an item names: itself, the files of a folder (those with an extension brdffit reads), or a glob's
    matches."""
    path = Path(item)
    if path.is_dir():
        known = {ext for f in FORMATS.values() for ext in f.extensions}
        return sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in known)
    if path.exists() or not glob.has_magic(item):
        return [path]
    matches = sorted(Path(p) for p in glob.glob(item, recursive=True) if Path(p).is_file())
    if not matches:
        raise FileNotFoundError(f"{item}: no file matches this pattern")
    return matches


def expand_sources(items) -> list[Source]:
    """The sources named by paths, folders, globs, ``FILE::GROUP`` strings and `Source` objects, in order, each
    once. No file is opened here: a brdffit HDF5 file without ``/measurements`` is found to stand for its material
    groups when a worker reads it (`read_sources`).

    Arguments:
        items: a path, a glob, or a sequence of them (str, Path, `Source`).

    Returns:
        The sources, duplicates dropped.

    Raises:
        FileNotFoundError: a path that does not exist or a glob that matches nothing.
        ValueError: no sources at all.
    """
    if isinstance(items, (str, Path, Source)):
        items = [items]
    sources: dict[str, Source] = {}
    for item in items:
        if isinstance(item, Source):
            found = [item]
        elif GROUP_SEPARATOR in str(item):
            path, group = str(item).split(GROUP_SEPARATOR, 1)
            found = [Source(str(Path(path).resolve()), group.strip("/"))]
        else:
            found = []
            for path in _files(str(item)):
                if not path.exists():
                    raise FileNotFoundError(f"{path}: no such file")
                found.append(Source(str(path.resolve())))
        for source in found:
            sources.setdefault(source.key, source)
    if not sources:
        raise ValueError("no sources: give files, folders, globs or FILE::GROUP names")
    return list(sources.values())
