"""The disk cache (harness/common/disk_cache.py): found again only for the same arguments and code, shared by
processes, bounded, and an unusable folder or entry costs the computation, never the result."""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from harness.common import disk_cache
from harness.common.disk_cache import cached, code_digest

ROOT = Path(__file__).resolve().parents[3]


def _module(tmp_path: Path, name: str, body: str):
    path = tmp_path / f"{name}.py"
    path.write_text(textwrap.dedent(body))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    where = tmp_path / "cache"
    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, str(where))
    monkeypatch.delenv(disk_cache.CACHE_MAX_MB_ENV, raising=False)
    return where


def _counting(tmp_path, name="square"):
    calls = []

    def square(n: int) -> dict:
        calls.append(n)
        return {"x": np.arange(n, dtype=np.float32) ** 2}

    code = _module(tmp_path, f"code_{name}", "VALUE = 1\n")
    return cached(name, square, key_of=lambda n: str(n).encode(), code_of=(code,)), calls, code


def test_a_result_that_is_not_a_dict_of_arrays_is_refused(cache_dir):
    with pytest.raises(TypeError, match="a dict of numeric arrays"):
        cached("objects", lambda n: {"x": np.array([object()] * n)}, key_of=lambda n: b"o", code_of=())(2)


def test_computed_once_for_the_same_arguments_and_again_for_others(cache_dir, tmp_path):
    f, calls, _ = _counting(tmp_path)
    a = f(5)
    b = f(5)
    assert calls == [5] and a["x"].tobytes() == b["x"].tobytes() == (np.arange(5, dtype=np.float32) ** 2).tobytes()
    f(6)
    assert calls == [5, 6]
    assert any(cache_dir.iterdir())


def test_an_edited_module_is_a_new_entry_never_a_stale_one(cache_dir, tmp_path):
    f, calls, code = _counting(tmp_path)
    f(3)
    before = code_digest(code)
    Path(code.__file__).write_text("VALUE = 2\n")  # the code the result depends on changed
    assert code_digest(code) != before
    g = cached("square", f.__wrapped__, key_of=lambda n: str(n).encode(), code_of=(code,))
    g(3)
    assert calls == [3, 3]


def test_another_process_reads_the_entry_back(cache_dir, tmp_path):
    """Two separate processes: the second finds what the first computed (the test workers' and the render child's
    case)."""
    log = tmp_path / "computed.log"
    script = tmp_path / "use_cache.py"
    script.write_text(textwrap.dedent(f"""
        import numpy as np
        from harness.common.disk_cache import cached
        import harness.common.seeding as code

        def slow(n):
            with open({str(log)!r}, "a") as f:
                f.write(f"{{n}}\\n")
            return {{"x": np.full(n, 7.0)}}

        out = cached("slow", slow, key_of=lambda n: str(n).encode(), code_of=(code,))(4)
        assert out["x"].tolist() == [7.0] * 4
    """))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for _ in range(2):
        subprocess.run([sys.executable, str(script)], check=True, env=env, cwd=ROOT, timeout=120)
    assert log.read_text().split() == ["4"]


@pytest.mark.parametrize("value", ["off", "", "OFF", "none", "0"])
def test_turned_off_computes_every_time_and_writes_nothing(tmp_path, monkeypatch, value):
    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, value)
    assert disk_cache.cache_location() is None
    f, calls, _ = _counting(tmp_path)
    f(2)
    f(2)
    assert calls == [2, 2]


def test_default_location_is_the_users_cache_folder(tmp_path, monkeypatch):
    monkeypatch.delenv(disk_cache.CACHE_DIR_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert disk_cache.cache_location() == tmp_path / "xdg" / "rt2"


def _value_files(where: Path) -> list[Path]:
    return list(where.rglob("*.val"))


# Hostile cache folders and entries: each costs a warning and the computation, never a wrong result or an error.
def _truncate(where):
    for p in _value_files(where):
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 3])


def _garbage(where):
    for p in _value_files(where):
        p.write_bytes(b"\x80\x05not an npz archive at all" * 10)


def _pickled(where):
    """A planted pickle that would run code when unpickled: never unpickled (np.load with allow_pickle=False)."""
    import pickle

    class Boom:
        def __reduce__(self):
            return (os.system, ("touch /tmp/rt2-disk-cache-pwned",))

    for p in _value_files(where):
        p.write_bytes(pickle.dumps(Boom()))


def _delete(where):
    for p in _value_files(where):
        p.unlink()


def _corrupt_index(where):
    (where / "cache.db").write_bytes(b"this is not an SQLite database" * 100)


@pytest.mark.parametrize("damage, warns", [
    (_truncate, "could not be read back"),  # a value file cut short (a full disk, a killed copy)
    (_garbage, "could not be read back"),  # another program's bytes
    (_pickled, "could not be read back"),  # a pickle planted to run code: refused, not run
    (_delete, None),  # the value file gone: diskcache reports a miss
    (_corrupt_index, "cannot be used"),  # the SQLite index overwritten
], ids=["truncated", "garbage", "pickle", "deleted", "index"])
def test_a_damaged_entry_is_computed_again(cache_dir, tmp_path, damage, warns):
    f, calls, _ = _counting(tmp_path, name=f"dmg_{damage.__name__}")
    f(40000)  # large enough to be stored in a file of its own
    assert _value_files(cache_dir)
    damage(cache_dir)
    disk_cache._open.cache_clear()  # a new process opens the damaged folder
    if warns:
        with pytest.warns(UserWarning, match=warns):
            out = f(40000)
    else:
        out = f(40000)
    assert calls == [40000, 40000]
    assert out["x"].tobytes() == (np.arange(40000, dtype=np.float32) ** 2).tobytes()
    assert not Path("/tmp/rt2-disk-cache-pwned").exists()


def test_a_folder_that_cannot_be_made_costs_a_warning_not_the_result(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, str(blocker / "cache"))
    f, calls, _ = _counting(tmp_path)
    with pytest.warns(UserWarning, match="cannot be used"):
        out = f(3)
    assert calls == [3] and out["x"].tolist() == [0.0, 1.0, 4.0]


@pytest.mark.parametrize("value", ["lots", "-5", "0", "nan", "inf"])
def test_a_bad_size_limit_warns_and_keeps_the_default(cache_dir, tmp_path, monkeypatch, value):
    monkeypatch.setenv(disk_cache.CACHE_MAX_MB_ENV, value)
    f, calls, _ = _counting(tmp_path, name=f"limit_{abs(hash(value))}")
    with pytest.warns(UserWarning, match=f"RT2_CACHE_MAX_MB={value!r} is not a positive number"):
        f(3)
    assert calls == [3]


def test_the_folder_stays_within_its_size_limit(cache_dir, tmp_path, monkeypatch):
    monkeypatch.setenv(disk_cache.CACHE_MAX_MB_ENV, "1")  # 1 MB; each entry ~0.4 MB
    f, calls, _ = _counting(tmp_path, name="bounded")
    for n in range(100_000, 100_010):
        f(n)
    size = sum(p.stat().st_size for p in _value_files(cache_dir))
    assert size <= 1.6e6  # diskcache culls after a store: the limit plus at most the last entry
    f(100_009)  # the newest is kept
    assert calls.count(100_009) == 1
    f(100_000)  # the oldest went first
    assert calls.count(100_000) == 2


def test_the_static_lab_read_back_is_the_ray_cast_byte_for_byte(cache_dir):
    """The simulated lab's static background: cold (computed), warm (read back in a new process's place) and the
    plain computation give the same arrays, read-only as before."""
    from harness.sim.render import static
    from tracker import Rig

    camera = Rig.load(ROOT / "data/rigs/lab4_vga.yaml").cameras[0]
    fresh = static._render(camera, 2, 0.2)
    cold = static.background(camera)
    static._CACHE.clear()  # as a new process would start
    warm = static.background(camera)
    assert cold is not warm
    for name, arr in fresh.items():
        for bg in (cold, warm):
            got = getattr(bg, name)
            assert got.dtype == arr.dtype and got.shape == arr.shape and got.tobytes() == arr.tobytes(), name
            assert not got.flags.writeable
    assert _value_files(cache_dir)


def test_launcher_flights_read_back_are_the_drawn_ones(cache_dir):
    from harness.live.sources.sim import LauncherFlights, _draw_flights

    drawn = _draw_flights(3, 2, 0.3, 1.5)
    for _ in range(2):  # cold, then warm
        got = LauncherFlights(3, n_serves=2)
        assert got._starts == drawn["starts"].tolist() and len(got._flights) == 2
        for i, (t1, s1) in enumerate(got._flights):
            assert drawn[f"times_{i}"].tobytes() == t1.tobytes() and drawn[f"states_{i}"].tobytes() == s1.tobytes()
    assert LauncherFlights(3, n_serves=2, gap_s=0.5).cycle_s == pytest.approx(got.cycle_s + 0.4)


def test_an_entry_that_would_fill_the_disk_is_not_stored(cache_dir, tmp_path, monkeypatch):
    """A session log or a recording on the same disk matters more than a cache: below the free-space margin the
    result is returned, not stored, with a warning."""
    import shutil

    f, calls, _ = _counting(tmp_path, name="full_disk")
    real = shutil.disk_usage
    monkeypatch.setattr(disk_cache.shutil, "disk_usage",
                        lambda p: real(p)._replace(free=disk_cache.MIN_FREE_AFTER_BYTES + 1000))
    with pytest.warns(UserWarning, match="not stored, .* MB free"):
        out = f(50_000)  # 200 kB of arrays: over the 1000 bytes left above the margin
    assert out["x"].shape == (50_000,) and not _value_files(cache_dir)
    with pytest.warns(UserWarning, match="keeps 2 GiB free"):
        f(50_000)
    assert calls == [50_000, 50_000]


def test_rt2_cache_info_and_clear(cache_dir, tmp_path, capsys):
    from harness.cli import main

    f, _, _ = _counting(tmp_path, name="shown")
    f(40000)
    assert main(["cache", "info"]) == 0
    assert f"the disk cache at {cache_dir}: 1 shown;" in capsys.readouterr().out
    assert main(["cache", "info", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["location"] == str(cache_dir) and s["entries"] == {"shown": 1} and s["bytes"] > 160_000
    assert main(["cache", "clear"]) == 0
    assert "1 entries" in capsys.readouterr().out
    assert not _value_files(cache_dir)
    main(["cache", "info", "--json"])
    assert json.loads(capsys.readouterr().out)["entries"] == {}


def test_a_relative_folder_is_made_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, "rel/cache")
    assert disk_cache.cache_location() == tmp_path / "rel" / "cache"


# Hostile cache folders for `rt2 cache`: one line naming the folder, exit 2; off is no error.
@pytest.mark.parametrize("make, code, says", [
    (lambda p: p.write_text("a file, not a folder"), 2, "is not a folder"),
    (lambda p: (p.mkdir(), (p / "cache.db").write_bytes(b"not sqlite" * 100)), 2, "cannot be opened"),
    (lambda p: None, 0, "nothing; 0.0 MB"),  # not made yet: empty, nothing created
], ids=["file", "corrupt-index", "missing"])
@pytest.mark.parametrize("command", ["info", "clear"])
def test_rt2_cache_on_hostile_folders(tmp_path, monkeypatch, capsys, make, code, says, command):
    from harness.cli import main

    where = tmp_path / "cache"
    make(where)
    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, str(where))
    assert main(["cache", command]) == code
    out, err = capsys.readouterr()
    if code:
        assert says in err and str(where) in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    elif command == "info":
        assert says in out and not where.exists()
    else:
        assert "0 entries" in out and not where.exists()


def test_rt2_cache_when_off(monkeypatch, capsys):
    from harness.cli import main

    monkeypatch.setenv(disk_cache.CACHE_DIR_ENV, "off")
    for command in ("info", "clear"):
        assert main(["cache", command]) == 0
        assert "the disk cache is off (RT2_CACHE_DIR='off')" in capsys.readouterr().out


def test_code_by_name_is_found_not_imported(tmp_path, monkeypatch):
    """A module named by its dotted name is read from its file, not imported (the launcher's scipy stays unloaded
    where flights are read back), and gives the digest its module object gives."""
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "rt2_digest_probe.py").write_text("raise RuntimeError('imported')\n")
    by_name = code_digest("rt2_digest_probe")  # would raise if imported
    assert "rt2_digest_probe" not in sys.modules
    assert code_digest("harness.common.seeding") == code_digest(importlib.import_module("harness.common.seeding"))
    assert by_name != code_digest("harness.common.seeding")
    with pytest.raises(ValueError, match="'no.such.module' has no source file"):
        code_digest("no.such.module")


def test_reading_flights_back_does_not_import_the_launcher(cache_dir):
    """rt2 track's start: the flights read back from the cache need no launcher (its aiming, its solver)."""
    from harness.live.sources.sim import LauncherFlights

    LauncherFlights(4, n_serves=1)  # drawn (the launcher imported here), stored
    code = ("import sys; from harness.live.sources.sim import LauncherFlights; LauncherFlights(4, n_serves=1); "
            "print('harness.sim.launcher' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False"]


def test_a_row_the_index_marks_as_pickled_is_refused_not_unpickled(cache_dir, tmp_path):
    """diskcache unpickles a row whose index says "pickle": a row planted that way (another program, an old
    format) is refused with a warning and computed again; the planted code never runs."""
    import diskcache

    f, calls, _ = _counting(tmp_path, name="planted")
    f(40000)
    marker = tmp_path / "pwned"

    class Boom:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    plain = diskcache.Cache(str(cache_dir))  # a writer that pickles, as another program would
    for key in list(plain.iterkeys()):
        plain.set(key, Boom())
    plain.close()
    disk_cache._open.cache_clear()
    with pytest.warns(UserWarning, match="pickled value: rt2 never unpickles"):
        out = f(40000)
    assert calls == [40000, 40000] and out["x"].shape == (40000,) and not marker.exists()
