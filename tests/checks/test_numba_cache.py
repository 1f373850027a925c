"""numba's disk cache keyed on the helpers a kernel compiles in: an edit in another file is never served stale."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

HELPER = """
import numba
SCALE = {scale}
@numba.njit(cache=True)
def scale(x):
    return SCALE * x
"""
KERNEL = """
import numba
from pkg.helper import scale
@numba.njit(cache=True)
def kernel(x):
    return scale(x) + 1.0
{keyed}
"""
KEYED = "from checks.numba_cache import key_cache_on_callees\nkey_cache_on_callees(globals())"


def _run(tmp_path) -> tuple[float, int]:
    code = "from pkg.kern import kernel; print(kernel(1.0), sum(kernel.stats.cache_hits.values()))"
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{ROOT}")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    value, hits = out.split()
    return float(value), int(hits)


@pytest.mark.parametrize("keyed", [True, False])
def test_an_edited_helper_in_another_file_recompiles_the_kernel(tmp_path, keyed):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "kern.py").write_text(KERNEL.format(keyed=KEYED if keyed else ""))
    (pkg / "helper.py").write_text(HELPER.format(scale=2.0))
    assert _run(tmp_path) == (3.0, 0)  # compiled, saved to the cache
    assert _run(tmp_path) == (3.0, 1)  # loaded from the cache
    (pkg / "helper.py").write_text(HELPER.format(scale=3.0))  # the kernel's own file is untouched
    if keyed:
        assert _run(tmp_path) == (4.0, 0)  # compiled afresh
        assert _run(tmp_path) == (4.0, 1)  # and cached under the new key
    else:  # numba alone: the old machine code, what `make clean-numba` used to be needed for
        assert _run(tmp_path) == (3.0, 1)


def test_every_module_with_cached_kernels_keys_its_cache():
    missing = []
    for path in sorted(ROOT.glob("*/**/*.py")):
        if path.parts[len(ROOT.parts)] not in ("checks", "tracker", "robot_models", "policies", "harness"):
            continue
        text = path.read_text()
        if re.search(r"cache\s*=\s*True", text) and "key_cache_on_callees(globals())" not in text:
            missing.append(str(path.relative_to(ROOT)))
    assert not missing, f"cached numba kernels without key_cache_on_callees(globals()) at the end: {missing}"


def test_the_digest_follows_helpers_into_other_files_and_constants():
    from checks.numba_cache import callee_digest, callees
    from policies import _ball_integrate, _hitting_return
    from tracker import _robust_kernels, distortion

    def names(disp):
        return {Path(f).name for f in callees(disp)[0]}

    assert names(_robust_kernels._project) == {"_robust_kernels.py", "distortion.py"}
    assert names(_hitting_return._outcome_nb) == {"_hitting_return.py", "_ball_integrate.py"}
    assert names(distortion.distort_point) == {"distortion.py"}
    assert callee_digest(distortion.distort_point) != callee_digest(_robust_kernels._project)
