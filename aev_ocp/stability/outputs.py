"""Saving and loading the stability analyses (manifest kinds ``stability``: ``aev-ocp stability``'s
stability.json; ``ring_stability``: ``--ring N``'s ring_stability.json; ``mixed_ring_stability``: ``--ring N
--aev LAW``'s mixed_ring_stability.json).

The manifest names the JSON document with its SHA-256 (:func:`aev_ocp.saved.read_document`); a loaded analysis
is a :class:`StabilityOutput` that rebuilds the linear analyses and measured attenuations from the document's
model-unit values and plots them with :mod:`aev_ocp.stability.plots`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..results import FieldsRepr
from ..saved import MANIFEST, LoadError, read_document, save_output
from .linear import LinearStability
from .measure import Attenuation

#: The JSON document of each kind.
DOCUMENTS = {
    "stability": "stability.json",
    "ring_stability": "ring_stability.json",
    "mixed_ring_stability": "mixed_ring_stability.json",
}


def save_stability_manifest(out: str | Path, kind: str, settings: dict[str, Any] | None = None) -> list[Path]:
    """The manifest of an analysis whose document (:data:`DOCUMENTS` [kind]) is already in ``out``."""
    if kind not in DOCUMENTS:
        raise ValueError(f"save_stability_manifest: kind {kind!r} is not one of {tuple(DOCUMENTS)}")
    return save_output(out, kind, {}, settings=settings, document=DOCUMENTS[kind])


def _model(entry: dict[str, Any], names: tuple[str, ...]) -> dict[str, Any]:
    """The entry's values of ``names``: the ``<name>_model`` value when the table has one, else ``<name>``."""
    return {n: entry[f"{n}_model"] if f"{n}_model" in entry else entry[n] for n in names}


def linear_of(entry: dict[str, Any], law: str) -> LinearStability:
    """The :class:`LinearStability` of one speed's entry of stability.json (its model-unit values)."""
    names = tuple(f.name for f in fields(LinearStability) if f.name != "law")
    d = _model(entry, names)
    band = d["unstable_band"]
    d["unstable_band"] = tuple(band) if band else None
    d["poles"] = tuple(complex(re, im) for re, im in d["poles"])
    return LinearStability(law=law, **d)


def attenuation_of(table: dict[str, Any]) -> Attenuation:
    """The :class:`Attenuation` of one measured run's table (its model-unit values)."""
    return Attenuation(**_model(table, tuple(f.name for f in fields(Attenuation))))


@dataclass(repr=False)
class StabilityOutput(FieldsRepr):
    """A loaded stability analysis: its kind (:data:`DOCUMENTS`), the JSON document as written, the folder."""

    kind: str
    document: dict[str, Any]
    folder: Path
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def law(self) -> str:
        """The analysed law's name (a mixed ring: 'human+aev')."""
        d = self.document
        if self.kind == "stability":
            return str(d["law"]["law"])
        if self.kind == "ring_stability":
            return str(d["law"])
        return f"{d['human_law']}+{d['aev_law']}"

    def linear(self) -> list[LinearStability]:
        """stability: the linear analysis at each speed (none for an MPC platoon)."""
        if self.kind != "stability":
            return []
        return [linear_of(e, self.law) for e in self.document["speeds"] if "criterion_model" in e]

    def measured(self) -> dict[str, list[Attenuation]]:
        """stability: the measured runs per speed, labelled ``v* = <model speed>`` as the run labelled them."""
        if self.kind != "stability":
            return {}
        return {
            f"v* = {float(e['v_star_model']):g}": [attenuation_of(t) for t in e.get("measured") or []]
            for e in self.document["speeds"]
        }

    def eigenvalues_per_s(self) -> list[list[float]]:
        """ring_stability: every mode's eigenvalues; mixed_ring_stability: the rightmost ones ([re, im], 1/s)."""
        if self.kind == "ring_stability":
            return [lam for mode in self.document["modes"] for lam in mode]
        if self.kind == "mixed_ring_stability":
            return list(self.document["eigenvalues_per_s"])
        return []

    def plot(self) -> Any:
        """A matplotlib Figure: stability: the measured attenuation against amplitude (dashed: the linear
        prediction), or without measured runs |G(iω)| of each speed; the ring kinds: the eigenvalues."""
        from .plots import plot_attenuation, plot_eigenvalues, plot_gain

        if self.kind != "stability":
            return plot_eigenvalues(self.eigenvalues_per_s(), title=f"{self.kind}: {self.law}")
        series = {k: v for k, v in self.measured().items() if v}
        if series:
            refs = {
                f"v* = {float(e['v_star_model']):g}": attenuation_of(e["linear_prediction"])
                for e in self.document["speeds"]
                if e.get("linear_prediction")
            }
            return plot_attenuation(series, refs, title=f"{self.law}: attenuation vs amplitude")
        return plot_gain(self.linear(), title=f"|G(iω)| of {self.law}")

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        d = self.document
        keys = ("growth_rate_per_s", "ring_stable", "v_star_mps", "min_aev_count")
        return f"StabilityOutput ({self.kind}): {self.law}", [(k, d[k]) for k in keys if k in d]


def load_stability_output(m: dict[str, Any], folder: Path) -> StabilityOutput:
    """The :class:`StabilityOutput` of a stability folder from its manifest (used by :func:`aev_ocp.load`)."""
    kind = m["kind"]
    doc = read_document(m, folder)
    if not isinstance(doc, dict):
        raise LoadError(f"{folder / str(m['document'])}: not a JSON object (the {kind} document is one)")
    need = {
        "stability": ("law", "speeds"),
        "ring_stability": ("law", "modes"),
        "mixed_ring_stability": ("eigenvalues_per_s",),
    }
    for key in need[kind]:
        if key not in doc:
            raise LoadError(f"{folder / str(m['document'])}: field {key!r} is missing (a {kind} document has it)")
    meta = {"output": {"path": str(folder), "kind": kind, "provenance": m.get("provenance"), "manifest": MANIFEST}}
    return StabilityOutput(kind, doc, folder, meta)
