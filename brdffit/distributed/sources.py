"""What a database fit reads: one material per source, a file of any format `brdffit.io.load` reads or one group
of a multi-material brdffit HDF5 file (docs/batch.md).

A multi-material HDF5 file holds several groups in the layout of ``/measurements`` (docs/formats.md), e.g.
``/materials/red`` and ``/materials/blue``, written with `brdffit.io.update_hdf5` and
`brdffit.io.hdf5.write_measurements_group`. A source names one of them as ``FILE::GROUP``; the file alone stands
for all of them (or for its ``/measurements`` group where it has one).
"""

from __future__ import annotations

import dataclasses
import glob
from pathlib import Path

from ..io import FORMATS, FormatError, detect_format, load, read_hdf5
from ..io.hdf5 import MEASUREMENTS_GROUP, open_hdf5
from ..measurements import Measurements

__all__ = ["Source", "GROUP_SEPARATOR", "expand_sources", "material_groups"]

GROUP_SEPARATOR = "::"

# A group holds a material when it has the datasets every /measurements group has (brdffit.io.hdf5).
_MATERIAL_DATASETS = ("theta_i", "phi_i", "theta_o", "phi_o", "values")


@dataclasses.dataclass(frozen=True)
class Source:
    """One material of a database.

    Attributes:
        path: the file, absolute (workers may run in another folder).
        group: the HDF5 group holding the material, or None for a file that is one material.
    """

    path: str
    group: str | None = None

    @property
    def key(self) -> str:
        """The source's name in the results table: ``PATH`` or ``PATH::GROUP``."""
        return self.path if self.group is None else f"{self.path}{GROUP_SEPARATOR}{self.group}"

    def load(self, read_options: dict | None = None) -> Measurements:
        """Read the material.

        Arguments:
            read_options: keywords of `brdffit.io.load` (table options, MERL ``subsample``, ...); not for groups.

        Returns:
            The `Measurements`.

        Raises:
            FormatError, MeasurementError, FileNotFoundError: from the reader, naming the file.
        """
        if self.group is None:
            return load(self.path, **(read_options or {}))
        return read_hdf5(self.path, group=self.group)


def material_groups(path) -> list[str]:
    """The groups of a brdffit HDF5 file that hold a material, in file order (``/measurements`` first).

    Raises:
        FormatError: not a brdffit HDF5 file.
    """
    import h5py

    found = []
    with open_hdf5(path) as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Group) and all(isinstance(obj.get(d), h5py.Dataset) for d in _MATERIAL_DATASETS):
                found.append(name)
        f.visititems(visit)
    return sorted(found, key=lambda name: name != MEASUREMENTS_GROUP)


def _files(item: str) -> list[Path]:
    """The files an item names: itself, the files of a folder (those with an extension brdffit reads), or a glob's
    matches."""
    path = Path(item)
    if path.is_dir():
        known = {ext for exts in FORMATS.values() for ext in exts}
        return sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in known)
    if path.exists() or not glob.has_magic(item):
        return [path]
    matches = sorted(Path(p) for p in glob.glob(item, recursive=True) if Path(p).is_file())
    if not matches:
        raise FileNotFoundError(f"{item}: no file matches this pattern")
    return matches


def expand_sources(items) -> list[Source]:
    """The materials named by paths, folders, globs, ``FILE::GROUP`` strings and `Source` objects, in order,
    each once.

    A brdffit HDF5 file with a ``/measurements`` group is one material; one without it stands for every group that
    holds a material (`material_groups`).

    Arguments:
        items: a path, a glob, or a sequence of them (str, Path, `Source`).

    Returns:
        The sources, duplicates dropped.

    Raises:
        FileNotFoundError: a path that does not exist or a glob that matches nothing.
        FormatError: an HDF5 file brdffit cannot read, or one with no material in it.
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
                found.extend(_file_sources(path.resolve()))
        for source in found:
            sources.setdefault(source.key, source)
    if not sources:
        raise ValueError("no sources: give files, folders, globs or FILE::GROUP names")
    return list(sources.values())


def _file_sources(path: Path) -> list[Source]:
    """One source for a file, or one per material group of a multi-material HDF5 file."""
    try:
        if detect_format(path) != "hdf5":
            return [Source(str(path))]
        groups = material_groups(path)
    except (FormatError, OSError):
        return [Source(str(path))]  # reading it reports the problem in its row, without stopping the others
    if MEASUREMENTS_GROUP in groups or not groups:
        return [Source(str(path))]
    return [Source(str(path), group) for group in groups]
