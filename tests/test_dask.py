"""squkf.dask: the fleet on Dask, against Fleet.batch_filter in one process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

dask = pytest.importorskip("dask")
da = pytest.importorskip("dask.array")
dd = pytest.importorskip("dask.dataframe")
pd = pytest.importorskip("pandas")
distributed = pytest.importorskip("distributed")

from models import (  # noqa: E402
    line_fleet,
    line_measurements,
    nan_for_big_line_fx,
    pushed_line_fx,
    slow_line_fx,
)

import squkf.dask as sd  # noqa: E402
from squkf import ParameterError, ShapeError  # noqa: E402

TESTS = Path(__file__).resolve().parent
FIELDS = (
    "means", "P1_2s", "variances", "log_likelihood", "failed", "x", "P1_2", "rejected", "nis", "y_whitened",
    "log_det_S1_2",
)  # fmt: skip


def same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            x, y = np.asarray(x), np.asarray(y)
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


def in_process(fleet, zs, **options):
    return fleet.subset(slice(None)).batch_filter(zs, **options)


@pytest.mark.parametrize("chunks", [(40, 12, 2), (7, 5, 1), (1, 12, 2), (25, -1, -1)])
@pytest.mark.parametrize("keep", ["all", "diagonals", "means", "final", ("means", "whitened")])
def test_bit_identical_to_the_fleet_whatever_the_chunking(chunks, keep):
    fleet = line_fleet(40, per_filter_R=True)
    zs = line_measurements(40, 12)
    before = fleet.x, fleet.P1_2
    lazy = sd.batch_filter(fleet, da.from_array(zs, chunks=chunks), keep=keep)
    assert isinstance(lazy.log_likelihood, da.Array)
    got = sd.compute(lazy, scheduler="synchronous")
    same(got, in_process(fleet, zs, keep=keep))
    assert (got.y_whitened is not None) == (keep == ("means", "whitened"))
    assert np.array_equal(fleet.x, before[0]) and np.array_equal(fleet.P1_2, before[1])  # template unchanged


def test_fields_computed_separately_agree_and_threads_scheduler():
    fleet = line_fleet(30)
    zs = line_measurements(30, 8)
    lazy = sd.batch_filter(fleet, da.from_array(zs, chunks=(10, 8, 2)))
    ref = in_process(fleet, zs)
    assert np.array_equal(lazy.means.compute(scheduler="threads"), ref.means)
    assert np.array_equal(lazy.P1_2s.compute(scheduler="threads"), ref.P1_2s)


def test_a_failing_filter_is_flagged_and_the_others_are_untouched():
    K, T = 24, 10
    fleet = line_fleet(K, fx=nan_for_big_line_fx)
    x = fleet.x
    x[13, 0] = 1e7  # filter 13's fx returns NaN: it fails at the first step
    fleet.x = x
    zs = line_measurements(K, T)
    got = sd.compute(sd.batch_filter(fleet, da.from_array(zs, chunks=(5, T, 2))), scheduler="synchronous")
    assert got.failed.tolist() == [k == 13 for k in range(K)]
    assert np.array_equal(got.means[13], np.broadcast_to(x[13], (T, 2)))  # kept its state
    others = np.arange(K) != 13
    clean = line_fleet(K).subset(others)
    ref = clean.batch_filter(zs[others])
    assert np.array_equal(got.means[others], ref.means)
    assert np.array_equal(got.P1_2s[others], ref.P1_2s)


@pytest.mark.parametrize(
    "zs, error",
    [
        (np.zeros((39, 5, 2)), ShapeError),  # K mismatched with the template
        (np.zeros((40, 5, 3)), ShapeError),  # dim_z mismatched
        (np.zeros((40, 5)), ShapeError),
        (np.zeros((40, 5, 2), dtype=complex), ShapeError),
    ],
)
def test_bad_input_raises_before_anything_is_scheduled(zs, error):
    with dask.config.set(scheduler="synchronous"):
        with pytest.raises(error):
            sd.batch_filter(line_fleet(40), da.from_array(zs))


def test_bad_options():
    with pytest.raises(ParameterError):
        sd.batch_filter(line_fleet(4), da.zeros((4, 3, 2)), keep="some")
    with pytest.raises(ParameterError):
        sd.batch_filter(line_fleet(4), da.zeros((4, 3, 2)), keep=("final", "whitened"))
    with pytest.raises(ParameterError):
        sd.batch_filter(line_fleet(4), da.zeros((4, 3, 2)), hx_args=[1])
    with pytest.raises(ParameterError):
        sd.batch_filter(object(), da.zeros((4, 3, 2)))


def test_importing_squkf_does_not_import_dask():
    code = "import sys, squkf; print(any(m == 'dask' or m.startswith('dask.') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_worker_environ_adds_the_mmap_threshold_and_keeps_dasks_settings():
    base = dask.config.get("distributed.nanny.pre-spawn-environ")
    env = sd.worker_environ()
    assert env["MALLOC_MMAP_THRESHOLD_"] == sd.MMAP_THRESHOLD == 16 * 2**20
    assert {k: v for k, v in env.items() if k != "MALLOC_MMAP_THRESHOLD_"} == base  # dask's own kept
    assert dask.config.get("distributed.nanny.pre-spawn-environ") == base  # the config is not changed
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": 4096}):
        assert sd.worker_environ()["MALLOC_MMAP_THRESHOLD_"] == 4096  # a user's value wins


def _mmap_threshold():
    return os.environ.get("MALLOC_MMAP_THRESHOLD_")


# -- a distributed cluster on this machine -------------------------------------------------------


@pytest.fixture
def cluster(monkeypatch):
    # worker processes import the model functions by name: put this folder on their path
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    # the nanny writes its pre-spawn variables into this process's environment; workers must get
    # them from the nanny (not inherit them from here), and they are undone when the test ends
    saved = dict(os.environ)
    os.environ.pop("MALLOC_MMAP_THRESHOLD_", None)
    c = sd.local_cluster(2, host="127.0.0.1", dashboard_address=None, silence_logs=40)
    client = distributed.Client(c)
    try:
        info = client.scheduler_info()["workers"].values()
        assert len(info) == 2 and all(w["nthreads"] == 1 for w in info)  # local_cluster's defaults
        yield client
    finally:
        client.close()
        c.close()
        os.environ.clear()
        os.environ.update(saved)


@pytest.mark.slow
def test_local_cluster_gives_the_same_numbers(cluster):
    fleet = line_fleet(60, per_filter_R=True)
    zs = line_measurements(60, 10)
    got = sd.compute(sd.batch_filter(fleet, da.from_array(zs, chunks=(15, 10, 2))))
    same(got, in_process(fleet, zs))


@pytest.mark.slow
def test_a_worker_killed_mid_computation_changes_nothing(cluster):
    K, T = 40, 40  # slow_fx: about 0.8 s per chunk
    fleet = line_fleet(K, fx=slow_line_fx)
    zs = line_measurements(K, T)
    lazy = sd.batch_filter(fleet, da.from_array(zs, chunks=(5, T, 2)), keep="means")
    futures = cluster.compute([lazy.means, lazy.log_likelihood])
    pids = cluster.run(os.getpid)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # wait until a chunk is running
        if any(cluster.processing().values()):
            break
        time.sleep(0.05)
    time.sleep(0.3)
    victim = next(iter(pids.values()))
    os.environ.pop("MALLOC_MMAP_THRESHOLD_", None)  # the replacement gets it from its nanny, not from here
    os.kill(victim, signal.SIGKILL)
    means, loglik = cluster.gather(futures)
    ref = fleet.subset(slice(None)).batch_filter(zs, keep="means")
    assert np.array_equal(means, ref.means)
    assert np.array_equal(loglik, ref.log_likelihood)
    assert victim not in cluster.run(os.getpid).values()  # the worker really was replaced
    # the nanny started the new worker with worker_environ's environment too
    assert set(cluster.run(_mmap_threshold).values()) == {str(sd.MMAP_THRESHOLD)}


# -- long-format frames ----------------------------------------------------------------------------


def long_frame(n_series=12, seed=3):
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n_series):
        T = 5 + k % 4
        for t in rng.permutation(T):  # rows in any order within a series
            rows.append({"series": k, "t": float(t), "r": 1.5 + rng.normal(), "v": rng.normal()})
    df = pd.DataFrame(rows)
    df.loc[3, "v"] = np.nan
    return df


def test_filter_frame_matches_a_fleet_per_series():
    df = long_frame()
    frame = dd.from_pandas(df, npartitions=3).set_index("series", sorted=False)
    template = line_fleet(1)
    x0 = pd.DataFrame({"p": np.linspace(-1, 1, 12), "v": 0.0}, index=range(12))
    out = sd.filter_frame(
        frame, template, key="series", time="t", columns=["r", "v"], x0=x0, state_names=["p", "v"]
    )
    assert list(out.columns) == ["p", "v", "std_p", "std_v", "failed"]
    got = out.compute(scheduler="synchronous")
    src = frame.compute()
    assert len(got) == len(src) and np.array_equal(got.index.to_numpy(), src.index.to_numpy())
    for k in range(12):  # each series against one filter run over it in time order
        rows = src.loc[[k]].reset_index()
        order = np.argsort(rows["t"].to_numpy(), kind="stable")
        f = template.subset([0])
        f.x = x0.loc[k].to_numpy()
        ref = f.batch_filter(rows[["r", "v"]].to_numpy()[order][None], keep="diagonals")
        est = got.loc[[k]].reset_index(drop=True).iloc[order]
        np.testing.assert_array_equal(est[["p", "v"]].to_numpy(), ref.means[0])
        np.testing.assert_array_equal(est[["std_p", "std_v"]].to_numpy(), np.sqrt(ref.variances[0]))


def test_filter_frame_rejects_frames_it_cannot_filter_per_series():
    df = long_frame()
    template = line_fleet(1)
    unindexed = dd.from_pandas(df, npartitions=3)  # the key is a column: a series may be split
    with pytest.raises(ParameterError, match="sorted index"):
        sd.filter_frame(unindexed, template, key="series", time="t", columns=["r", "v"])
    frame = dd.from_pandas(df, npartitions=3).set_index("series")
    with pytest.raises(ParameterError, match="no column"):
        sd.filter_frame(frame, template, key="series", time="t", columns=["r", "speed"])
    with pytest.raises(ShapeError):
        sd.filter_frame(frame, template, key="series", time="t", columns=["r"])
    # unknown divisions: nothing says a series is not split across partitions
    split = dd.from_pandas(df, npartitions=3).set_index("series", sorted=False).clear_divisions()
    with pytest.raises(ParameterError, match="known divisions"):
        sd.filter_frame(split, template, key="series", time="t", columns=["r", "v"])


@pytest.mark.parametrize(
    "values",
    [
        lambda v: v.astype(str),  # text, even of numbers
        lambda v: pd.to_datetime(np.arange(v.size), unit="s"),  # would be read as nanoseconds
        lambda v: pd.to_timedelta(np.arange(v.size), unit="s"),
        lambda v: pd.Categorical(v),  # would be read as the categories' codes
        lambda v: v + 1j,  # would lose its imaginary part
        lambda v: pd.Series(v, dtype=object),
    ],
)
def test_filter_frame_refuses_a_measurement_column_that_is_not_numbers_before_scheduling(values):
    df = long_frame()
    df["v"] = values(df["v"].to_numpy())
    frame = _indexed(df)
    dtype = frame.dtypes["v"]
    with dask.config.set(scheduler=_no_scheduling), pytest.raises(ParameterError) as info:
        sd.filter_frame(frame, line_fleet(1), key="series", time="t", columns=["r", "v"])
    assert "'v'" in str(info.value) and f"dtype {dtype}" in str(info.value)


def _indexed(df):
    # divisions known from pandas (set_index on the dask frame would compute them)
    return dd.from_pandas(df.set_index("series").sort_index(kind="stable"), npartitions=3)


def _no_scheduling(*args, **kwargs):
    raise AssertionError("a task was scheduled")


@pytest.mark.parametrize(
    "values",
    [
        lambda v: v > 0,  # bool: 0 and 1, as numpy and squkf read bools
        lambda v: pd.array(np.where(np.isnan(v), None, np.round(10 * v)), dtype="Int64"),  # NA missing
        lambda v: pd.array(np.where(np.isnan(v), None, v), dtype="Float64"),
        lambda v: v.astype(np.float32),
    ],
)
def test_filter_frame_reads_integer_bool_and_nullable_columns_as_floats(values):
    df = long_frame()
    df["v"] = values(df["v"].to_numpy())
    as_float = df.assign(v=df["v"].to_numpy(dtype=float, na_value=np.nan))
    assert np.isnan(as_float["v"]).sum() == (1 if df["v"].dtype != bool else 0)
    template = line_fleet(1)
    got, want = (
        sd.filter_frame(
            _indexed(d),
            template,
            key="series",
            time="t",
            columns=["r", "v"],
        ).compute(scheduler="synchronous")
        for d in (df, as_float)
    )
    pd.testing.assert_frame_equal(got, want, check_exact=True)


def test_per_filter_arguments_are_cut_by_chunk_bit_identical():
    K, T = 9, 6
    fleet = line_fleet(K, fx=pushed_line_fx)
    zs = line_measurements(K, T)
    push = np.linspace(-0.5, 0.5, K)
    want = in_process(fleet, zs, fx_args={"push": push})
    for chunks in [(2, -1, -1), (4, 3, 1), (9, -1, -1)]:
        got = sd.compute(sd.batch_filter(fleet, da.from_array(zs, chunks=chunks), fx_args={"push": push}))
        same(got, want)
    shared = in_process(fleet, zs, fx_args={"push": 0.25})  # a scalar is shared, as in one process
    same(
        sd.compute(sd.batch_filter(fleet, da.from_array(zs, chunks=(2, -1, -1)), fx_args={"push": 0.25})),
        shared,
    )
    # a shared array as long as a chunk would be read per filter by that chunk's fleet: refused
    with pytest.raises(ParameterError, match=r"fx_args\['push'\] has a leading axis of 3"):
        sd.batch_filter(fleet, da.from_array(zs, chunks=(3, -1, -1)), fx_args={"push": np.zeros(3)})


def test_filter_frame_reports_the_series_that_failed():
    df = long_frame()
    frame = dd.from_pandas(df, npartitions=3).set_index("series", sorted=False)
    template = line_fleet(1, fx=nan_for_big_line_fx)
    x0 = pd.DataFrame({"p": np.where(np.arange(12) == 5, 1e7, 0.0), "v": 0.0}, index=range(12))
    got = sd.filter_frame(frame, template, key="series", time="t", columns=["r", "v"], x0=x0).compute(
        scheduler="synchronous"
    )
    assert got["failed"].dtype == bool
    assert got.groupby(level=0)["failed"].all().to_dict() == {k: k == 5 for k in range(12)}


# -- squkf.dask.fit_noise (issue 37): the shared=False fits a task per chunk of recordings --------------


@pytest.mark.slow
def test_fit_noise_on_a_cluster_is_the_fits_in_process_whatever_the_chunking(cluster):
    from models import tune_cv_filter

    from squkf import simulate, tune

    _, zs = simulate(tune_cv_filter(), 80, 6, seed=5)
    template = tune_cv_filter(q=1.0, r1=1.0, r2=1.0)
    options = {"Q": tune.Scaled(), "R": tune.Diagonal()}
    here = tune.fit_noise(template, zs, shared=False, **options)
    for per_task in (4, 6):
        there = sd.fit_noise(template, zs, recordings_per_task=per_task, **options)
        assert len(there) == 6
        for a, b in zip(here, there):
            for name in ("theta", "Q", "R", "theta_cov"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
            assert a.log_likelihood == b.log_likelihood and a.success == b.success


def test_fit_noise_on_a_cluster_refuses_before_scheduling():
    from models import tune_cv_filter

    template = tune_cv_filter()
    with pytest.raises(ParameterError, match="shared"):
        sd.fit_noise(template, np.zeros((2, 10, 2)), shared=True)
    with pytest.raises(ParameterError, match="recordings_per_task"):
        sd.fit_noise(template, np.zeros((2, 10, 2)), recordings_per_task=0)
    with pytest.raises(ShapeError, match="zs"):
        sd.fit_noise(template, np.zeros((2, 10, 3)))
