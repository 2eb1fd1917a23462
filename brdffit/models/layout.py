"""The parameter layout of a sum of lobes, computed once per structure.

Every piece of code that maps a lobe's own parameter names to the model's, flattens parameter values into a
vector, or labels the entries ``name`` / ``name[i]`` asks the `Layout` (as JAX computes a pytree's structure
once). `layout(lobes, channels)` is cached, so asking costs nothing after the first time.

Model-level names: the k-th lobe declaring a name gets ``name_k``, unless another lobe declares that name itself
(Lafortune's ``ks_2``) or it is already taken; then the count goes on to the next free suffix. So
``"lambert+ward+ward"`` has ``rho_d, ks, alpha, ks_2, alpha_2`` and ``"phong+phong+lafortune(lobes=2)"`` gives
the second Phong ``ks_3`` and ``n_3``, since ``ks_2`` and ``n_2`` belong to Lafortune's second lobe.

Shared parameters: a lobe whose ``share`` option names a parameter (`Lobe.shared`) has no slot of its own for it;
it reads the slot of the nearest earlier lobe declaring that name. ``"lambert+ggx+ggx(share=f0)"`` has
``rho_d, ks, alpha, f0, ks_2, alpha_2``, and both GGX lobes read ``f0``.
"""

from __future__ import annotations

import dataclasses
import math
import functools
from collections import Counter

from .._lazy import module
from ..params import ParamSpec, ParamTable

np = module("numpy")  # loaded on first use: the registry (`brdffit models`) does not need it

__all__ = ["Slot", "Layout", "layout"]


@dataclasses.dataclass(frozen=True)
class Slot:
    """One parameter of a model.

    Attributes:
        name: the model-level name.
        local: the name its lobe declares.
        lobe: index of the lobe in the sum.
        spec: the declaration under the model-level name.
        shape: ``(channels,)`` for a colour parameter, ``()`` for a shape parameter.
    """

    name: str
    local: str
    lobe: int
    spec: ParamSpec
    shape: tuple

    @property
    def size(self) -> int:
        """Number of scalars."""
        return math.prod(self.shape)  # not np.prod: it builds an array, and the engine asks per parameter per pass

    def labels(self) -> list[str]:
        """``[name]`` for a scalar, ``[name[0], name[1], ...]`` per channel."""
        return [self.name] if not self.shape else [f"{self.name}[{i}]" for i in range(self.size)]


class Layout:
    """Names, declarations, shapes, offsets, labels and roles of a model's parameters.

    Arguments:
        lobes: the lobes of the sum, in order.
        channels: number of channels.
    """

    def __init__(self, lobes: tuple, channels: int):
        self.lobes = tuple(lobes)
        self.channels = int(channels)
        self._incidence: dict = {}  # `channel_incidence` by names
        declared = {spec.name for lobe in self.lobes for spec in lobe.param_specs()}
        seen: Counter[str] = Counter()
        taken: set[str] = set()
        slots = []
        latest: dict[str, Slot] = {}  # local name -> the slot the last lobe declaring it reads
        per_lobe = []
        for j, lobe in enumerate(self.lobes):
            own = []  # the slots this lobe reads, in its declaration order
            specs = lobe.param_specs()
            if lobe.bounded:  # every amplitude at most 1: ks·F ≤ 1 wherever F reaches 1 (the plausibility check)
                specs = tuple(dataclasses.replace(spec, upper=1.0, default=min(spec.default, 1.0))
                              if spec.linear and math.isinf(spec.upper) else spec for spec in specs)
            _check_shared(j, lobe, specs, latest)
            for spec in specs:
                if spec.name in lobe.shared:
                    own.append(latest[spec.name])
                    continue
                seen[spec.name] += 1
                name = spec.name
                if seen[spec.name] > 1:
                    count = seen[spec.name]
                    while f"{spec.name}_{count}" in declared or f"{spec.name}_{count}" in taken:
                        count += 1
                    seen[spec.name] = count
                    name = f"{spec.name}_{count}"
                taken.add(name)
                slot = Slot(name, spec.name, j, spec.renamed(name), (self.channels,) if spec.colour else ())
                slots.append(slot)
                own.append(slot)
            latest.update({slot.local: slot for slot in own})
            per_lobe.append(tuple(own))
        self.slots: tuple[Slot, ...] = tuple(slots)
        self._per_lobe: tuple[tuple[Slot, ...], ...] = tuple(per_lobe)
        self.specs = ParamTable(slot.spec for slot in slots)
        self.names: tuple[str, ...] = self.specs.names
        self._by_name = {slot.name: slot for slot in slots}

    def __getitem__(self, name: str) -> Slot:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"no parameter {name!r}; parameters are {', '.join(self.names)}") from None

    def lobe_slots(self, j: int) -> tuple[Slot, ...]:
        """The slots lobe ``j`` reads, one per parameter it declares, in its declaration order (a shared
        parameter's slot belongs to the earlier lobe that owns it: ``slot.lobe != j``)."""
        return self._per_lobe[j]

    def local_params(self, params: dict, j: int) -> dict:
        """Lobe ``j``'s parameters under its own names, from model-level ``params``."""
        return {slot.local: params[slot.name] for slot in self.lobe_slots(j)}

    def global_names(self, j: int, local: dict) -> dict:
        """Lobe ``j``'s local name -> value dict under model-level names (the inverse of `local_params`)."""
        mapping = {slot.local: slot.name for slot in self.lobe_slots(j)}
        return {mapping[k]: v for k, v in local.items()}

    def partners(self, j: int, local: str) -> tuple[str, ...]:
        """Model-level names of the parameters of lobe ``j`` that act only through its amplitude ``local``
        (`Lobe.amplitude_partners`)."""
        mapping = {slot.local: slot.name for slot in self.lobe_slots(j)}
        # A parameter another lobe reads too (shared) does not act only through this amplitude.
        elsewhere = {slot.name for k in range(len(self.lobes)) if k != j for slot in self.lobe_slots(k)}
        return tuple(mapping[p] for p in self.lobes[j].amplitude_partners(local) if mapping[p] not in elsewhere)

    def linear(self, names) -> tuple[str, ...]:
        """The names among ``names`` declared linear (amplitudes), in model order."""
        names = set(names)
        return tuple(slot.name for slot in self.slots if slot.name in names and slot.spec.linear)

    def size(self, names) -> int:
        """Number of scalars of the named parameters."""
        return sum(self[name].size for name in names)

    def offsets(self, names) -> dict:
        """name -> slice of its scalars in a vector that flattens ``names`` in the given order."""
        out, start = {}, 0
        for name in names:
            out[name] = slice(start, start + self[name].size)
            start += self[name].size
        return out

    def labels(self, names) -> list[str]:
        """Labels of the scalars of ``names``: ``name`` or ``name[i]`` per channel."""
        return [label for name in names for label in self[name].labels()]

    def flatten(self, tree: dict, names, xp=np):
        """Concatenate the named values of ``tree`` into one vector (``xp``: numpy or jax.numpy)."""
        if not names:
            return xp.zeros(0)
        return xp.concatenate([xp.ravel(xp.asarray(tree[name])) for name in names])

    def unflatten(self, vector, names, xp=np) -> dict:
        """The inverse of `flatten`: name -> value with the parameter's shape."""
        return {name: xp.reshape(vector[s], self[name].shape) for name, s in self.offsets(names).items()}

    def channel_incidence(self, names) -> tuple[np.ndarray, np.ndarray]:
        """For each scalar of ``names`` (flattened order): the index of its name, and the channels it acts on
        ``(P, C)`` (every channel for a shape parameter, its own for a colour parameter). Read-only arrays, made once
        per ``names`` (every pass of a solve asks)."""
        key = tuple(names)
        if key not in self._incidence:
            self._incidence[key] = self._channel_incidence(key)
        return self._incidence[key]

    def _channel_incidence(self, names: tuple) -> tuple[np.ndarray, np.ndarray]:
        index, incidence = [], []
        for q, name in enumerate(names):
            if self[name].shape:
                index.extend([q] * self.channels)
                incidence.extend(np.eye(self.channels))
            else:
                index.append(q)
                incidence.append(np.ones(self.channels))
        index, incidence = np.asarray(index, dtype=int), np.asarray(incidence).reshape(-1, self.channels)
        index.flags.writeable = incidence.flags.writeable = False
        return index, incidence


def _check_shared(j: int, lobe, specs, latest: dict) -> None:
    """Raise a ValueError naming the lobe if its ``share`` option cannot be resolved: an unknown name, no earlier
    lobe declaring it, an amplitude, or an earlier declaration that differs (bounds, colour)."""
    if not isinstance(lobe.share, str):
        raise ValueError(f"lobe {j + 1} ({lobe.name}): share must be parameter names separated by spaces, got "
                         f"{lobe.share!r}")
    own = {spec.name: spec for spec in specs}
    for name in lobe.shared:
        where = f"lobe {j + 1} ({lobe.token()}) shares {name!r}"
        if name not in own:
            raise ValueError(f"{where}, which it does not declare; its parameters: {', '.join(own)}")
        if name not in latest:
            raise ValueError(f"{where}, but no lobe before it declares {name!r}")
        if own[name].linear:
            raise ValueError(f"{where}: an amplitude cannot be shared (each lobe's amplitude is its own)")
        if latest[name].spec.renamed(name) != own[name]:
            raise ValueError(f"{where}, but the earlier lobe declares it differently ({latest[name].spec} against "
                             f"{own[name]})")


@functools.lru_cache(maxsize=256)
def layout(lobes: tuple, channels: int) -> Layout:
    """The (cached) `Layout` of a sum of lobes with ``channels`` channels."""
    return Layout(lobes, channels)
