"""First use: the line said on a compile, ``squkf.precompile``, and no writable cache location.

Each compile is observed in a fresh process through numba's event API (``"numba:compile"``), with
``NUMBA_CACHE_DIR`` pointed at an empty folder of the test's own, so that what the process finds in
the cache is known.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numba
import numpy as np
import pytest
from models import CV3_NZ, CV_Z, cv_filter, make_cv3_fleet

import squkf
from squkf.kernels import cache, phases

ROOT = Path(squkf.__file__).resolve().parents[1]  # the squkf under test
TESTS = Path(__file__).resolve().parent
LINE = "squkf: compiling"  # how the line said on a compile starts
END = "squkf: compiled in "  # how the line said when that compile has ended starts

#: Counts, in a subprocess, the compiles of squkf's kernels through numba's event API; prints them last.
COUNT_COMPILES = """
import atexit, json
from numba.core import event
compiles = []

class Count(event.Listener):
    def on_start(self, ev):
        fn = ev.data["dispatcher"].py_func
        compiles.append(fn.__name__ if fn.__module__ == "squkf.kernels.phases" else "user's " + fn.__name__)

    def on_end(self, ev):
        pass

event.register("numba:compile", Count())
atexit.register(lambda: print(json.dumps(compiles)))
"""

#: A few entry kernels of squkf.linalg (each with its helpers): several compiles, in a few seconds.
SOME_KERNELS = """
import numpy as np
from squkf.linalg import chol_update, solve_lower, tria
S = np.linalg.cholesky(np.array([[2.0, 0.5], [0.5, 1.0]]))
tria(np.vstack([S, S]))
solve_lower(S, S[:, 0])
chol_update(S, 0.1 * S[:, 0], 1.0)
"""


def run_python(code: str, cache_dir: Path, path: Path = ROOT, **env: str) -> subprocess.CompletedProcess:
    """``code`` in a new process: squkf from ``path``, numba's cache in ``cache_dir``; its compiles last."""
    environ = {k: v for k, v in os.environ.items() if k not in ("SQUKF_QUIET_COMPILE", "NUMBA_CACHE_DIR")}
    environ.update(PYTHONPATH=str(path), NUMBA_CACHE_DIR=str(cache_dir), **env)
    return subprocess.run(
        [sys.executable, "-c", COUNT_COMPILES + code],
        capture_output=True,
        text=True,
        env=environ,
        cwd=TESTS,
    )


def compiles(out: subprocess.CompletedProcess) -> list[str]:
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def said(out: subprocess.CompletedProcess) -> list[str]:
    return [line for line in out.stderr.splitlines() if line.startswith(LINE)]


def said_ended(out: subprocess.CompletedProcess) -> list[float]:
    """The seconds that the lines said at the end of a compile give."""
    lines = [line for line in out.stderr.splitlines() if line.startswith(END)]
    return [float(re.fullmatch(r"squkf: compiled in (\d+\.\d) s", line).group(1)) for line in lines]


def steps_of_a_filter_and_a_fleet() -> dict[str, list]:
    """A per-point filter's steps over ``CV_Z`` and a fleet's two steps: their state, as lists."""
    f = cv_filter()
    for z in CV_Z:
        f.predict()
        f.update(z)
    fleet = make_cv3_fleet()
    for t in range(2):
        fleet.predict()
        fleet.update(np.full((3, CV3_NZ), 0.5 * t))
    return {"x": f.x.tolist(), "P": f.P.tolist(), "fleet x": fleet.x.tolist(), "fleet P": fleet.P.tolist()}


# -- the line said on a compile ----------------------------------------------------------------------------


def test_a_compile_is_said_once_with_the_cache_and_a_cache_load_or_a_users_function_says_nothing(tmp_path):
    cache_dir = tmp_path / "numba"
    cold = run_python(SOME_KERNELS, cache_dir)
    compiled = compiles(cold)
    assert len(set(compiled)) >= 3  # several kernels compiled (with their helpers)
    (line,) = said(cold)
    assert str(cache_dir) in line and "SQUKF_QUIET_COMPILE" in line
    user = "import numba\nnumba.njit(lambda v: v + 1)(1.0)\n"
    warm = run_python(SOME_KERNELS + user, cache_dir)
    assert compiles(warm) == ["user's <lambda>"]  # squkf's kernels loaded from the cache
    assert said(warm) == []


def test_a_compile_says_how_long_it_usually_takes_what_may_compile_later_and_when_it_ended(tmp_path):
    cache_dir = tmp_path / "numba"
    cold = run_python(SOME_KERNELS + "import time\ntime.sleep(0.1)\n" + SOME_KERNELS, cache_dir)
    (line,) = said(cold)
    assert "typically 10-60 s, once" in line
    assert "angle hooks, a partial z or the smoother may compile once more" in line
    assert "python -m squkf precompile" in line
    (seconds,) = said_ended(cold)  # several kernels, one compile said, one end
    lines = cold.stderr.splitlines()
    assert lines.index(line) < next(i for i, text in enumerate(lines) if text.startswith(END))
    assert 0.0 < seconds < 600.0
    warm = run_python(SOME_KERNELS, cache_dir)
    assert said(warm) == [] and said_ended(warm) == []
    quiet = run_python(SOME_KERNELS, tmp_path / "other", SQUKF_QUIET_COMPILE="1")
    assert said(quiet) == [] and said_ended(quiet) == []


def test_a_later_compile_in_the_same_process_is_said_with_its_kernel_and_its_end(tmp_path):
    """A route first used after the first compile has ended (issue 36's unexplained pauses): its
    kernel's compile is said by a line of its own, and its end; with the cache, nothing is said."""
    later = (
        "from squkf.kernels import cache\n"
        "cache.end_of_compile()\n"  # as after QUIET_PERIOD without a compile
        "from squkf.kernels.wrappers import finite_rows\n"
        "finite_rows(np.ones((2, 3)))\n"
    )
    cold = run_python(SOME_KERNELS + later, tmp_path / "numba")
    assert "finite_rows_kernel" in compiles(cold)
    first, second = said(cold)
    assert "typically 10-60 s" in first
    assert "compiling finite_rows_kernel for a route first used in this process" in second
    assert "python -m squkf precompile" in second and "SQUKF_QUIET_COMPILE" in second
    assert len(said_ended(cold)) == 2
    lines = cold.stderr.splitlines()
    order = ["start" if s.startswith(LINE) else "end" for s in lines if s.startswith("squkf: compil")]
    assert order == ["start", "end", "start", "end"]
    warm = run_python(SOME_KERNELS + later, tmp_path / "numba")
    assert compiles(warm) == [] and said(warm) == [] and said_ended(warm) == []
    quiet = run_python(SOME_KERNELS + later, tmp_path / "other", SQUKF_QUIET_COMPILE="1")
    assert said(quiet) == [] and said_ended(quiet) == []


def test_precompile_says_it_compiles_every_kernel_not_first_use(tmp_path):
    """Its line (a run cut to squkf.linalg's workload, which leaves kernels unreached) and its end."""
    code = (
        "import squkf.first_use as fu\n"
        "fu.WORKLOADS = {'squkf.linalg': fu._linear_algebra}\n"
        "try:\n"
        "    fu.precompile()\n"
        "except RuntimeError:\n"
        "    print('unreached', flush=True)\n"
    )
    out = run_python(code, tmp_path / "numba")
    assert "unreached" in out.stdout
    (line,) = said(out)
    assert "every kernel" in line and "first use" not in line and "once more" not in line
    assert len(said_ended(out)) == 1


@pytest.mark.parametrize("value, silent", [("1", True), ("0", False)])
def test_squkf_quiet_compile_silences_the_line(tmp_path, value, silent):
    out = run_python(SOME_KERNELS, tmp_path / "numba", SQUKF_QUIET_COMPILE=value)
    assert len(compiles(out)) >= 3  # the compiles happened
    assert len(said(out)) == (0 if silent else 1)


def test_importing_squkf_compiles_nothing_and_says_nothing(tmp_path):
    out = run_python("import squkf\n", tmp_path / "numba")
    assert compiles(out) == [] and said(out) == []


# -- squkf.precompile ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_precompile_leaves_nothing_for_a_new_process_to_compile(tmp_path):
    """One cold run: ``python -m squkf precompile`` on an empty cache; then a filter and a fleet compile
    nothing, and a second precompile compiles nothing and finds every kernel."""
    cache_dir = tmp_path / "numba"
    environ = {k: v for k, v in os.environ.items() if k != "SQUKF_QUIET_COMPILE"}
    environ.update(PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(cache_dir))
    cold = subprocess.run(
        [sys.executable, "-m", "squkf", "precompile"], capture_output=True, text=True, env=environ
    )
    assert cold.returncode == 0, cold.stderr
    assert len(said(cold)) == 1 and len(said_ended(cold)) == 1
    assert "first use" not in cold.stderr
    summary = cold.stdout.strip().splitlines()[-1]
    assert str(cache_dir) in summary and " 0 functions compiled" not in summary
    code = (
        f"import sys; sys.path.insert(0, {str(TESTS)!r})\n"
        "from test_first_use import steps_of_a_filter_and_a_fleet\n"
        "steps_of_a_filter_and_a_fleet()\n"
        "import squkf\n"
        "done = squkf.precompile()\n"
        "print(done.kernels, done.compiled, done.cache_dir)\n"
    )
    warm = run_python(code, cache_dir)
    assert compiles(warm) == [] and said(warm) == []
    kernels, compiled, where = warm.stdout.splitlines()[-2].split(" ", 2)
    entries = [name for name in phases.__all__ if name.endswith("_kernel")]
    assert (int(kernels), int(compiled)) == (len(entries), 0)
    assert where.startswith(str(cache_dir))


def test_a_kernel_no_route_reaches_is_reported(monkeypatch):
    monkeypatch.setattr(cache, "_functions", set(cache._functions))  # the new kernel forgotten afterwards
    monkeypatch.setattr(phases, "orphan_kernel", cache.jit()(lambda a: a), raising=False)
    assert "orphan_kernel" in squkf.first_use.unreached()
    with pytest.raises(RuntimeError, match="compiled no code for orphan_kernel"):
        squkf.precompile()


@pytest.mark.parametrize("args", [[], ["compile"]])
def test_the_command_line_runs_nothing_without_its_command(args):
    out = subprocess.run([sys.executable, "-m", "squkf", *args], capture_output=True, text=True, cwd=ROOT)
    assert (out.returncode, out.stdout) == (2, "")


# -- no writable cache location -----------------------------------------------------------------------------


def _unwritable(tmp_path: Path) -> dict[str, str]:
    """Every place numba could cache in made impossible to create (a path under a regular file: root
    too is refused, unlike with permissions): ``NUMBA_CACHE_DIR``, the user-wide cache."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    return dict(
        NUMBA_CACHE_DIR=str(blocker / "numba"),
        XDG_CACHE_HOME=str(blocker / "xdg"),
        HOME=str(blocker / "home"),
    )


def test_with_no_cache_location_the_kernels_compile_in_memory_after_one_warning(tmp_path, monkeypatch):
    """numba's own search decides, once per source file; a kernel then compiles in memory and runs."""
    source = tmp_path / "module" / "mod.py"
    source.parent.mkdir()
    source.write_text("def double(a):\n    return 2.0 * a\n\n\ndef triple(a):\n    return 3.0 * a\n")
    (source.parent / "__pycache__").write_text("")  # a file where numba's folder beside the source would be
    spec = importlib.util.spec_from_file_location("squkf_first_use_probe", source)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    env = _unwritable(tmp_path)
    monkeypatch.setattr(numba.config, "CACHE_DIR", env.pop("NUMBA_CACHE_DIR"))
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(cache, "_functions", set())
    monkeypatch.setattr(cache, "_directories", {})
    monkeypatch.setattr(cache, "_said", True)  # the compiles below say nothing (nor their end, later)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        double, triple = cache.jit()(module.double), cache.jit()(module.triple)
    assert [(w.category, "NUMBA_CACHE_DIR" in str(w.message)) for w in caught] == [(RuntimeWarning, True)]
    assert cache.cache_label(module.double) == "in memory"
    assert double(1.5) + triple(1.0) == 6.0


def _unwritable_copy(tmp_path: Path) -> Path:
    """A copy of the package whose ``__pycache__`` beside the kernels cannot be made."""
    copy = tmp_path / "site"
    shutil.copytree(ROOT / "squkf", copy / "squkf", ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "squkf" / "kernels" / "__pycache__").write_text("")
    return copy


def test_the_no_cache_warning_points_at_the_users_import(tmp_path):
    """The warning names the line of the user's program that imported squkf, not squkf's source."""
    copy = _unwritable_copy(tmp_path)
    program = tmp_path / "program.py"
    program.write_text(
        "import json, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    import squkf\n"
        "print(json.dumps([(w.filename, w.lineno, 'NUMBA_CACHE_DIR' in str(w.message)) for w in caught]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("SQUKF_QUIET_COMPILE", "NUMBA_CACHE_DIR")}
    env.update(_unwritable(tmp_path), PYTHONPATH=str(copy))
    out = subprocess.run(
        [sys.executable, str(program)], capture_output=True, text=True, env=env, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [[str(program), 4, True]]


@pytest.mark.slow
def test_import_squkf_and_its_steps_work_with_no_writable_cache(tmp_path):
    """A copy of the package whose ``__pycache__`` cannot be made, and no other cache location: one
    warning naming NUMBA_CACHE_DIR, the line says "in memory", and the numbers equal a normal run's."""
    copy = _unwritable_copy(tmp_path)
    env = _unwritable(tmp_path)
    code = (
        f"import sys, warnings; sys.path.insert(0, {str(TESTS)!r})\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    import squkf\n"
        "    from test_first_use import steps_of_a_filter_and_a_fleet\n"
        "    numbers = steps_of_a_filter_and_a_fleet()\n"
        f"assert squkf.__file__.startswith({str(copy)!r})\n"
        "print(json.dumps(numbers))\n"
        "print(json.dumps([(w.category.__name__, str(w.message)) for w in caught]))\n"
    )
    out = run_python(code, Path(env.pop("NUMBA_CACHE_DIR")), path=copy, **env)
    assert out.returncode == 0, out.stderr
    assert len(compiles(out)) > 0
    (line,) = said(out)
    assert "in memory" in line
    numbers, caught = (json.loads(s) for s in out.stdout.strip().splitlines()[-3:-1])
    assert [(kind, "NUMBA_CACHE_DIR" in message) for kind, message in caught] == [("RuntimeWarning", True)]
    assert numbers == steps_of_a_filter_and_a_fleet()  # bit for bit: floats survive JSON exactly
