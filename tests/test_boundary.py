"""``squkf.boundary``: each check written once serves one filter (batch shape ``()``) and a fleet (``(K,)``).

The checks say the same of the same input whichever front end is given it;
a transaction puts a filter back on any error; a filter's configuration is
one record the other front ends read; and no module reaches into another's
private members, nor do the modules import each other in a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from models import CV3_K, CV3_NZ, assert_fleet_state, fleet_state, make_cv3_fleet

import squkf
from squkf import checks
from squkf.boundary import attributes, config, loop, records
from squkf.errors import FleetStepError, NonFiniteError, ParameterError, ShapeError

PACKAGE = Path(squkf.__file__).resolve().parent


def test_sizes_are_positive_integers_with_one_message():
    assert checks.check_sizes(dim_x=np.int64(3), dim_z=1) == (3, 1)
    for bad in (0, True, 2.0, "2"):
        with pytest.raises(ParameterError, match=r"dim_z must be a positive integer, got dim_z="):
            checks.check_sizes(dim_x=2, dim_z=bad)


def test_one_filters_measurement_and_a_stacks_read_the_same_components():
    z = np.array([1.0, np.nan, 3.0])
    one = checks.measurement(z, None, 3, lambda: 3, 0)
    assert one is not None
    arr, observed = one
    np.testing.assert_array_equal(observed, [True, False, True])
    stacked = checks.measurements(np.stack([z, z]), 2, 3)
    np.testing.assert_array_equal(~np.isnan(stacked[0]), observed)
    assert checks.measurement(np.full(3, np.nan), None, 3, lambda: 3, 0) is None
    with pytest.raises(NonFiniteError, match="inf"):
        checks.measurement(np.array([1.0, np.inf, 0.0]), None, 3, lambda: 3, 0)
    with pytest.raises(NonFiniteError, match=r"row 1"):
        checks.measurements(np.array([[1.0, 0.0, 0.0], [np.inf, 0.0, 0.0]]), 2, 3)
    with pytest.raises(ShapeError, match=r"z is None"):
        checks.measurements(None, 2, 3)


def test_a_series_of_steps_is_read_as_the_array():
    zs = np.arange(12.0).reshape(2, 3, 2)
    from_steps = checks.measurement_series(iter([zs[:, t] for t in range(3)]), 2, 2)
    np.testing.assert_array_equal(from_steps, checks.measurement_series(zs, 2, 2))
    with pytest.raises(ShapeError, match=r"zs\[1\]"):
        checks.measurement_series(iter([zs[:, 0], zs[:, 1, :1]]), 2, 2)


def test_a_given_covariance_is_factored_once_shared_or_per_filter():
    A = np.array([[4.0, 2.0], [2.0, 3.0]])
    S = checks.noise_factors(A, "R", 2, 3)
    np.testing.assert_allclose(S @ S.T, A)
    per = checks.noise_factors(np.stack([A, 2 * A, 3 * A]), "R", 2, 3)
    np.testing.assert_array_equal(per[0], S)
    np.testing.assert_allclose(per[2] @ per[2].T, 3 * A)
    with pytest.raises(ShapeError, match=r"expected \(2, 2\) or \(3, 2, 2\)"):
        checks.noise_factors(np.zeros((2, 2, 2)), "R", 2, 3)
    cache: dict = {}
    one = checks.noise_factor(A, "R", 2, lambda: None, cache)
    np.testing.assert_array_equal(one, np.linalg.cholesky(A))
    assert checks.noise_factor(A, "R", 2, lambda: None, cache) is one  # the same array: not factored again
    Ps = checks.covariance_factors(A, "P", 2, 3)
    assert Ps.shape == (3, 2, 2) and np.array_equal(Ps[1], Ps[0])


def test_an_edit_in_place_is_taken_once_through_the_setter_or_stays_pending():
    taken = []

    def assign(name, a):
        if np.isnan(a).any():
            raise NonFiniteError(f"{name} contains NaN")
        taken.append((name, a.copy()))

    out = attributes.HandOut()
    a = out.array("x", lambda: np.zeros(2))
    assert out.array("x", lambda: np.ones(2)) is a  # the same array until dropped
    out.take(["x"], assign)
    assert taken == []  # not edited: nothing to take
    a[0] = np.nan
    with pytest.raises(NonFiniteError):
        out.take(["x"], assign)
    copied = out.detached()  # a copy's own array, the edit pending there too
    a[0] = 1.0
    out.take(["x"], assign)
    out.take(["x"], assign)  # taken once
    assert [name for name, _ in taken] == ["x"] and taken[0][1].tolist() == [1.0, 0.0]
    with pytest.raises(NonFiniteError):
        copied.take(["x"], assign)
    a.shape = (1, 2)  # a change of shape in place is an edit too
    assert attributes.Handed(np.zeros(2)).edited() is False
    out.take(["x"], assign)
    assert taken[-1][1].shape == (1, 2)
    out.drop("x")
    assert out.array("x", lambda: np.ones(2)).tolist() == [1.0, 1.0]


def test_a_transaction_puts_back_what_was_taken_on_any_error():
    state = {"x": 1}
    taken = loop.Transaction(lambda: dict(state), lambda s: (state.clear(), state.update(s)))
    with pytest.raises(KeyboardInterrupt), taken:
        state["x"] = 2
        raise KeyboardInterrupt
    assert state == {"x": 1}
    with taken:
        state["x"] = 3
    assert state == {"x": 3}


def test_the_batch_loop_runs_each_step_and_puts_everything_back_on_an_error():
    """``loop.run_steps``, both faces' ``batch_filter`` loop: each step, the progress callable after it,
    and on an error at step k the state put back, the error annotated with k and the first k results
    (kept apart from the state, as a run's records are)."""
    state: dict = {"x": 0}
    results: list = []

    def transaction():
        return loop.Transaction(lambda: dict(state), lambda s: state.update(s))

    def step(k, item):
        if item is None:
            raise ParameterError("no item")
        state["x"] += item
        results.append(state["x"])

    told: list = []
    assert loop.run_steps(transaction(), [1, 2, 3], step, lambda k: results[:k], told.append, 3) == 3
    assert state["x"] == 6 and results == [1, 3, 6] and told == [0, 1, 2]
    results.clear()
    with pytest.raises(ParameterError, match="^at step 2: no item") as err:
        loop.run_steps(transaction(), [1, 1, None], step, lambda k: results[:k], None, 3)
    assert state["x"] == 6  # (put back)
    assert err.value.step == 2 and err.value.partial == [7, 8]

    def longer(T):
        raise ParameterError(f"dts has more than {T} entries")

    results.clear()
    with pytest.raises(ParameterError, match="^dts has") as err:  # after the steps: no step named
        loop.run_steps(transaction(), [4], step, lambda k: results[:k], None, None, longer)
    assert err.value.step is None and err.value.partial == [10] and state["x"] == 6


def test_a_fleet_run_that_fails_leaves_the_fleet_as_it_was():
    fleet = make_cv3_fleet()
    before = fleet_state(fleet)

    def failing_hx(X):
        raise RuntimeError("broken sensor")

    fleet.hx = failing_hx
    with pytest.raises(RuntimeError, match="broken sensor"):
        fleet.batch_filter(np.zeros((CV3_K, 4, CV3_NZ)))
    assert_fleet_state(fleet, before)


def test_the_fleets_failures_error_names_the_filters():
    exc = records.failures_error({4: "b", 1: "a"}, " while smoothing")
    assert isinstance(exc, FleetStepError)
    assert exc.filters == (1, 4) and exc.reasons == ("a", "b")
    assert str(exc).startswith("2 filter(s) failed numerically while smoothing: filter 1: a")
    assert squkf.FleetStepError is FleetStepError and squkf.FleetResult is records.FleetResult


def test_a_configuration_goes_from_a_fleet_to_a_filter_and_back():
    fleet = make_cv3_fleet()
    c = fleet.configuration()
    one = fleet[1]
    back = one.configuration()
    assert config.common_config([back, back]) is back
    assert (back.dim_x, back.dim_z, back.dt, back.fx, back.hx) == (c.dim_x, c.dim_z, c.dt, c.fx, c.hx)
    np.testing.assert_array_equal(back.R1_2, c.R1_2)
    assert config.filter_kwargs(back)["scheme"] is c.scheme
    with pytest.raises(ParameterError, match="differs in configuration"):
        config.common_config([back, back._replace(dt=2.0)])


def _imports(path: Path) -> set[str]:
    """The squkf modules a module imports, at its top or inside functions."""
    tree = ast.parse(path.read_text())
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    package = parts if path.name == "__init__.py" else parts[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[: len(package) - node.level + 1]
            mod = ".".join(base + ([node.module] if node.module else []))
            names = [mod] if node.module else [f"{mod}.{a.name}" for a in node.names]
            out.update(names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("squkf"))
    return out


def _modules() -> dict[str, set[str]]:
    graph = {}
    for path in PACKAGE.rglob("*.py"):
        if "kernels" in path.parts or "examples" in path.parts:
            continue
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        graph[name] = _imports(path)
    return graph


def test_the_front_ends_and_the_smoother_import_each_other_in_no_cycle():
    graph = _modules()
    known = {m: {d for d in deps if d in graph and d != m} for m, deps in graph.items()}
    seen: dict[str, int] = {}

    def visit(m, path):
        if seen.get(m) == 1:
            raise AssertionError(f"import cycle: {' -> '.join(path + [m])}")
        if seen.get(m) == 2:
            return
        seen[m] = 1
        for d in sorted(known[m]):
            if d != "squkf":  # the package's __init__ imports every front end, as it should
                visit(d, path + [m])
        seen[m] = 2

    for m in sorted(known):
        if m != "squkf":
            visit(m, [])


#: squkf's layers, bottom up (ARCHITECTURE.md): a module imports from its own layer and those below only.
LAYERS = {
    "the exceptions": ["squkf._version", "squkf.errors"],
    "kernels": [
        "squkf.kernels", "squkf.kernels.phases", "squkf.kernels.cache", "squkf.kernels.threads",
        "squkf.kernels.table", "squkf.kernels.wrappers",
    ],
    "plug-ins and support": [
        "squkf.angles", "squkf.blas", "squkf.rows", "squkf.weights", "squkf.generators", "squkf.gating",
        "squkf.noise", "squkf.checks", "squkf.linalg", "squkf.transform", "squkf.statuses",
        "squkf.measurement",
    ],
    "the plan": ["squkf.plan"],
    "the boundary": [
        "squkf.boundary", "squkf.boundary.attributes", "squkf.boundary.records",
        "squkf.boundary.loop", "squkf.boundary.config", "squkf.batch",
    ],
    "the engine": ["squkf.engine"],
    "the fleet's stacks": ["squkf.stacks"],
    "the faces": [
        "squkf", "squkf.__main__", "squkf.face", "squkf.ukf_state", "squkf.ukf_records", "squkf.ask_tell",
        "squkf.ukf", "squkf.fleet_state", "squkf.fleet_batch", "squkf.fleet", "squkf.fleet_from",
        "squkf.old_pickles", "squkf.smoother", "squkf.nag",
        "squkf.ut",
        "squkf.dask", "squkf.first_use", "squkf.examples", "squkf.examples.g13ej_example",
        "squkf.consistency", "squkf.simulate", "squkf.parametrise", "squkf.candidates", "squkf.noise_fit",
        "squkf.tune",
    ],
}  # fmt: skip
LEVEL = {m: k for k, mods in enumerate(LAYERS.values()) for m in mods}


def _all_modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        out[".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)] = path
    return out


def _module_of(name: str) -> str:
    """The squkf module an imported name belongs to (``squkf.engine.Route`` -> ``squkf.engine``)."""
    while name not in LEVEL and "." in name:
        name = name.rsplit(".", 1)[0]
    return name


def test_every_module_has_a_layer():
    assert set(_all_modules()) == set(LEVEL), set(_all_modules()) ^ set(LEVEL)


def test_no_module_imports_from_a_layer_above_its_own():
    """Bottom up: the exceptions, kernels, plug-ins and support, the plan, the boundary, the engine,
    the stacks, the faces."""
    layer = list(LAYERS)
    wrong = []
    for module, path in _all_modules().items():
        for imported in _imports(path):
            dep = _module_of(imported)
            if dep in LEVEL and LEVEL[dep] > LEVEL[module]:
                wrong.append(f"{module} ({layer[LEVEL[module]]}) imports {dep} ({layer[LEVEL[dep]]})")
    assert not wrong, wrong


def test_no_module_imports_another_modules_private_names():
    found = []
    for module, path in _all_modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("squkf")):
                found += [
                    f"{module}: {a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert not found, found


@pytest.mark.parametrize(
    "module", ["smoother", "batch", "dask", "boundary/config", "boundary/loop", "stacks"]
)
def test_no_module_reads_a_front_ends_private_members(module):
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    reads = [
        f"{node.value.id}.{node.attr}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr.startswith("_")
        and not node.attr.startswith("__")
        and isinstance(node.value, ast.Name)
        and node.value.id in ("ukf", "fleet", "f", "f0", "filters")
    ]
    assert not reads, reads
