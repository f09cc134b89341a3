"""Bad input never hurts the app: each bad demonstrations file or command line ends in ONE clear message.

One table of files (name, how to build it, expected message; None = a valid file that must load),
run three ways: `load_demonstrations`, the command line `python -m ifo demos check` (exit 2, one
`error: ...` line, no traceback) and the app's upload `storage.save_demos` (DemoError, and a good
file saved earlier under the same name stays intact). Bombs are built from streamed zeros, so the
tests never allocate more than a few MB.
"""
import io
import struct
import time
import zipfile
from functools import lru_cache

import numpy as np
import pytest
from numpy.lib import format as npy

import ifo.data.demos as demos_mod
from ifo.cli import main
from ifo.data.demos import DemoError, load_demonstrations
from ifo.data.npz import NpzError, npz_headers, read_npz
from ifo.envs import get_env
from ifo.ui import storage

CARTPOLE = get_env("cartpole")
USER = "tester01"


# ---------------------------------------------------------------------- building files
def good(episodes=3, length=5, with_actions=True, **changes) -> dict:
    rng = np.random.default_rng(0)
    n = episodes * length
    data = {"obs": rng.normal(size=(n, 4)).astype(np.float32), "rewards": np.ones(n, dtype=np.float32),
            "episode_starts": np.tile(np.eye(1, length, dtype=np.int8)[0], episodes)}
    if with_actions:
        data["actions"] = rng.integers(0, 2, size=n)
    return {**data, **changes}


def spoiled(spoil, **kw) -> dict:
    data = good(**kw)
    spoil(data)
    return data


def npz(arrays: dict, compressed=False) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def npy_header(shape, dtype) -> bytes:
    """A .npy header declaring `shape` and `dtype`, with no data after it."""
    buf = io.BytesIO()
    npy.write_array_header_1_0(buf, {"descr": npy.dtype_to_descr(np.dtype(dtype)), "fortran_order": False,
                                     "shape": tuple(shape)})
    return buf.getvalue()


def zip_of(members: dict, method=zipfile.ZIP_STORED) -> bytes:
    """A zip of name -> bytes, or name -> (header bytes, number of zero bytes streamed after it)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for name, content in members.items():
            if isinstance(content, tuple):
                head, zeros = content
                with zf.open(name, "w", force_zip64=True) as f:
                    f.write(head)
                    for start in range(0, zeros, 1 << 22):
                        f.write(bytes(min(1 << 22, zeros - start)))
            else:
                zf.writestr(name, content)
    return buf.getvalue()


def members(arrays: dict, **replace) -> dict:
    """The .npy members np.savez would write, with some replaced by raw bytes."""
    out = {f"{k}.npy": npy_bytes(v) for k, v in arrays.items()}
    return {**out, **replace}


def duplicate_member() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, arr in good().items():
            zf.writestr(f"{name}.npy", npy_bytes(arr))
        with pytest.warns(UserWarning, match="Duplicate name"):
            zf.writestr("obs.npy", npy_bytes(np.zeros((15, 4), np.float32)))
    return buf.getvalue()


def member_data_offset(blob: bytes, name: str) -> tuple[int, int]:
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        info = zf.getinfo(name)
    name_len, extra_len = struct.unpack_from("<HH", blob, info.header_offset + 26)
    return info.header_offset + 30 + name_len + extra_len, info.compress_size


def corrupt_deflate() -> bytes:
    """Flip bytes in the middle of obs.npy's compressed data."""
    data = good(episodes=20, length=50)
    data["obs"] = np.cumsum(data["obs"], axis=0)  # compressible, so deflate makes real Huffman blocks
    blob = bytearray(npz(data, compressed=True))
    start, size = member_data_offset(bytes(blob), "obs.npy")
    for i in range(start + size // 2, start + size // 2 + 16):
        blob[i] ^= 0xFF
    return bytes(blob)


def sizes_that_lie() -> bytes:
    """obs.npy holds half the data its header declares, and the zip's sizes claim all of it is there:
    only reading through a stream bounded by the .npy header notices."""
    head = npy_header((15, 4), np.float32)
    arrays = good(with_actions=False)
    blob = bytearray(zip_of(members(arrays, **{"obs.npy": head + bytes(120)}), zipfile.ZIP_DEFLATED))
    claimed = len(head) + 240
    with zipfile.ZipFile(io.BytesIO(bytes(blob))) as zf:
        info = zf.getinfo("obs.npy")
    struct.pack_into("<I", blob, info.header_offset + 22, claimed)  # local header
    cd = blob.find(b"PK\x01\x02")
    while blob[cd + 46: cd + 46 + 7] != b"obs.npy":  # this member's central directory entry
        cd = blob.find(b"PK\x01\x02", cd + 4)
    struct.pack_into("<I", blob, cd + 24, claimed)
    return bytes(blob)


@lru_cache(maxsize=None)
def bomb(rows: int) -> bytes:
    """`rows` states of zeros (obs, rewards, episode_starts), all those zeros really in the file, deflated."""
    return zip_of({"obs.npy": (npy_header((rows, 4), np.float32), rows * 16),
                   "rewards.npy": (npy_header((rows,), np.float32), rows * 4),
                   "episode_starts.npy": (npy_header((rows,), np.int8), rows)}, zipfile.ZIP_DEFLATED)


@lru_cache(maxsize=None)
def hidden_bomb() -> bytes:
    """obs.npy's header declares 15 states, and 32 MB of zeros follow it."""
    return zip_of(members(good(), **{"obs.npy": (npy_header((15, 4), "f4"), 32_000_000)}), zipfile.ZIP_DEFLATED)


@lru_cache(maxsize=None)
def with_huge_unknown_keys() -> bytes:
    """A valid file plus members that must never be opened: 10^12 declared rows, a 32 MB deflated
    array, a pickled object array and a text file."""
    return zip_of(members(good(), **{
        "frames.npy": npy_header((10**12, 84, 84), np.float32),
        "video.npy": (npy_header((2_000_000, 4), np.float32), 32_000_000),
        "infos.npy": npz({"x": np.array([{"a": 1}], dtype=object)}),
        "readme.txt": b"made by hand",
    }), zipfile.ZIP_DEFLATED)


def bad_npy_header() -> bytes:
    head = npy.MAGIC_PREFIX + bytes([1, 0]) + struct.pack("<H", 16) + b"{'descr': 5}   \n"
    return zip_of(members(good(), **{"obs.npy": head}))


def fortran_big_endian() -> bytes:
    data = good()
    data["obs"] = np.asfortranarray(data["obs"].astype(">f8"))
    return npz(data, compressed=True)


# ---------------------------------------------------------------------- the table
CASES = [
    ("not a zip", lambda: b"obs,rewards\n1,2\n", "not an .npz archive"),
    ("empty file", lambda: b"", "the file is empty"),
    ("zip without .npy members", lambda: zip_of({"notes.txt": b"hello"}),
     "missing key(s) 'obs', 'rewards', 'episode_starts'; found ['notes.txt']"),
    ("empty zip", lambda: zip_of({}), "missing key(s) 'obs', 'rewards', 'episode_starts'; found []"),
    ("a member that is not .npy", lambda: zip_of(members(good(), **{"obs.npy": b"just some text"})),
     "member 'obs.npy' is not a .npy array"),
    ("a .npy member with a bad header", bad_npy_header, "member 'obs.npy' has an invalid .npy header"),
    ("truncated archive", lambda: npz(good())[: len(npz(good())) // 2], "not an .npz archive, or a damaged one"),
    ("corrupt deflate stream", corrupt_deflate, "member 'obs.npy' is damaged"),
    ("the same key twice", duplicate_member, "holds 'obs' twice"),
    ("'obs' and 'obs.npy' both", lambda: zip_of(members(good(), obs=npy_bytes(good()["obs"]))), "holds 'obs' twice"),
    ("header declaring 10^12 rows", lambda: zip_of(members(good(), **{"obs.npy": npy_header((10**12, 4), "f4")})),
     "'obs' holds 1,000,000,000,000 states; at most 1,000,000 are accepted"),
    ("decompression bomb (2M rows of zeros)", lambda: bomb(2_000_000),
     "'obs' holds 2,000,000 states; at most 1,000,000 are accepted"),
    ("bomb hidden behind a small header", hidden_bomb,
     "member 'obs.npy' holds 32,000,000 data bytes but its .npy header declares 240"),
    ("data shorter than the header says", lambda: zip_of(members(good(), **{"obs.npy": npy_header((15, 4), "f4")})),
     "member 'obs.npy' holds 0 data bytes but its .npy header declares 240"),
    ("zip sizes that lie", sizes_that_lie, "member 'obs.npy' ends after 120 of the 240 data bytes"),
    ("object array (pickled)", lambda: npz(good(actions=np.array([{"a": 1}] * 15, dtype=object))),
     "'actions' holds Python objects (a pickled array)"),
    ("pickled obs", lambda: npz(good(obs=np.array([{"a": 1}] * 15, dtype=object))), "'obs' holds Python objects"),
    ("structured dtype", lambda: npz(good(obs=np.zeros(15, dtype=[("x", "f4"), ("v", "f4"), ("a", "f4")]))),
     "'obs' has dtype [('x', '<f4')"),
    ("text obs", lambda: npz(good(obs=good()["obs"].astype(str))), "'obs' has dtype <U"),
    ("complex obs", lambda: npz(good(obs=good()["obs"].astype(np.complex64))), "'obs' has dtype complex64"),
    ("missing required key", lambda: npz(spoiled(lambda d: d.pop("rewards"))), "missing key(s) 'rewards'"),
    ("unknown huge keys are ignored unread", with_huge_unknown_keys, None),
    ("wrong state shape", lambda: npz(good(obs=good()["obs"][:, :3])),
     "'obs' states have shape (3,) but cartpole states have shape (4,)"),
    ("obs of one dimension", lambda: npz(good(obs=good()["obs"][:, 0])), "'obs' has shape (15,); expected (N, 4)"),
    ("bool obs", lambda: npz(good(obs=good()["obs"] > 0)),
     "'obs' has dtype bool; states must be numbers (float or integer), not True/False"),
    ("NaN obs", lambda: npz(spoiled(lambda d: d["obs"].__setitem__((2, 1), np.nan))), "'obs' has 1 non-finite values"),
    ("inf obs", lambda: npz(spoiled(lambda d: d["obs"].__setitem__((4, 0), -np.inf))), "'obs' has 1 non-finite values"),
    ("1e300 in float64 obs", lambda: npz(good(obs=np.where(np.arange(60).reshape(15, 4) % 20 == 5, 1e300, 0.5))),
     "'obs' has 3 values beyond ±1e9 (largest 1e+300): states that large overflow float32 training"),
    ("3e38 in float32 obs", lambda: npz(spoiled(lambda d: d["obs"].__setitem__((3, 2), -3e38))),
     "'obs' has 1 values beyond ±1e9 (largest 3e+38)"),
    ("huge integer obs", lambda: npz(good(obs=np.full((15, 4), 2**62, dtype=np.int64))),
     "'obs' has 60 values beyond ±1e9"),
    ("1e300 in next_obs", lambda: npz(good(next_obs=np.full((15, 4), 1e300))), "'next_obs' has 60 values beyond ±1e9"),
    ("NaN rewards", lambda: npz(spoiled(lambda d: d["rewards"].__setitem__(3, np.nan))), "'rewards' has 1 non-finite"),
    ("1e300 rewards", lambda: npz(good(rewards=np.full(15, 1e300))), "'rewards' has 15 values beyond ±1e9"),
    ("rewards of the wrong length", lambda: npz(good(rewards=np.ones(14))),
     "'rewards' has shape (14,); expected (15,)"),
    ("episode_starts not 0/1", lambda: npz(spoiled(lambda d: d["episode_starts"].__setitem__(3, 2))),
     "'episode_starts' must hold only 0 and 1"),
    ("episode_starts[0] == 0", lambda: npz(spoiled(lambda d: d["episode_starts"].__setitem__(0, 0))),
     "'episode_starts' must be 1 at index 0"),
    ("actions out of range", lambda: npz(spoiled(lambda d: d["actions"].__setitem__(4, 7))),
     "'actions' range from 0 to 7; cartpole has actions 0..1"),
    ("negative actions", lambda: npz(spoiled(lambda d: d["actions"].__setitem__(4, -1))), "'actions' range from -1"),
    ("actions non-integer floats", lambda: npz(good(actions=np.full(15, 0.5))), "'actions' must be whole numbers"),
    ("NaN actions", lambda: npz(good(actions=np.full(15, np.nan))), "'actions' has 15 non-finite"),
    ("next_obs shape mismatch", lambda: npz(good(next_obs=good()["obs"][:3])), "'next_obs' has shape (3, 4)"),
    ("single-state episodes without next_obs", lambda: npz(good(episodes=2, length=1)),
     "every episode has a single state"),
    ("a single state", lambda: npz(good(episodes=1, length=1)), "'obs' holds 1 state(s); at least 2 are needed"),
    ("a 2-state file (smallest valid)", lambda: npz(good(episodes=1, length=2)), None),
    ("integer obs (trained as float32)", lambda: npz(good(obs=(good()["obs"] * 100).astype(np.int16))), None),
    ("compressed, Fortran-ordered, big-endian float64", fortran_big_endian, None),
]
IDS = [name for name, _, _ in CASES]


@pytest.fixture(autouse=True)
def runs_root(tmp_path, monkeypatch):
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))


@pytest.mark.parametrize("name,build,message", CASES, ids=IDS)
def test_load_demonstrations(tmp_path, name, build, message):
    path = tmp_path / "case.npz"
    path.write_bytes(build())
    if message is None:
        demos = load_demonstrations(path, CARTPOLE, (4,))
        assert len(demos.transitions) >= 1 and demos.transitions.states.dtype == np.float32
        return
    with pytest.raises(DemoError) as err:
        load_demonstrations(path, CARTPOLE, (4,))
    assert str(err.value).startswith(f"{path}: ")  # names the file
    assert message in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name,build,message", CASES, ids=IDS)
def test_cli_demos_check(tmp_path, capsys, name, build, message):
    path = tmp_path / "case.npz"
    path.write_bytes(build())
    status = main(["demos", "check", str(path), "--env", "cartpole"])
    out, err = capsys.readouterr()
    if message is None:
        assert status == 0 and out.startswith("ok: ") and err == ""
        return
    assert status == 2 and out == ""
    assert err.endswith("\n") and err.count("\n") == 1 and err.startswith("error: ")  # one line, no traceback
    assert message in err


@pytest.mark.parametrize("name,build,message", CASES, ids=IDS)
def test_upload(name, build, message):
    kept = storage.save_demos(USER, "cartpole", "case.npz", npz(good()))
    before = kept.path.read_bytes()
    if message is None:
        saved = storage.save_demos(USER, "cartpole", "case.npz", build())
        assert saved.path == kept.path and saved.summary["transitions"] >= 1
        return
    with pytest.raises(DemoError) as err:
        storage.save_demos(USER, "cartpole", "case.npz", build())
    assert str(err.value).startswith("case.npz: ") and message in str(err.value)
    assert kept.path.read_bytes() == before
    assert [d.name for d in storage.list_demos(USER)] == ["cartpole-case"]
    assert not [p for p in kept.path.parent.iterdir() if p.name.startswith(".")]  # no temporary file left


# ---------------------------------------------------------------------- bad command lines
CLI_CASES = [
    (["demos", "check", "{good}", "--env", "cartpole", "--image-size", "0"],
     "--image-size must be between 16 and 256 pixels, got 0"),
    (["demos", "check", "{good}", "--env", "maze3", "--image-size", "100000"],
     "--image-size must be between 16 and 256 pixels, got 100000"),
    (["experts", "evaluate", "--env", "cartpole", "--episodes", "0"], "--episodes must be a whole number >= 1, got 0"),
    (["experts", "evaluate", "--env", "cartpole", "--episodes", "-3"],
     "--episodes must be a whole number >= 1, got -3"),
    (["experts", "train", "--env", "cartpole", "--timesteps", "0"], "--timesteps must be a whole number >= 1, got 0"),
    (["demos", "check", "{good}", "--env", "pong"], "unknown environment 'pong'"),
    (["demos", "check", "{missing}", "--env", "cartpole"], "no such file"),
    (["demos", "check", "{folder}", "--env", "cartpole"], "is a folder"),
]


@pytest.mark.parametrize("args,message", CLI_CASES, ids=[" ".join(a) for a, _ in CLI_CASES])
def test_bad_command_lines_give_one_clear_line(tmp_path, capsys, args, message):
    good_file = tmp_path / "good.npz"
    good_file.write_bytes(npz(good()))
    paths = {"good": good_file, "missing": tmp_path / "nope.npz", "folder": tmp_path}
    status = main([a.format(**paths) for a in args])
    out, err = capsys.readouterr()
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err


# ---------------------------------------------------------------------- the reader itself
def test_unknown_members_are_never_opened(tmp_path, monkeypatch):
    path = tmp_path / "extra.npz"
    path.write_bytes(with_huge_unknown_keys())
    opened = []
    real_open = zipfile.ZipFile.open

    def spy(self, name, *args, **kw):
        opened.append(getattr(name, "filename", name))
        return real_open(self, name, *args, **kw)

    monkeypatch.setattr(zipfile.ZipFile, "open", spy)
    start = time.perf_counter()
    demos = load_demonstrations(path, CARTPOLE, (4,))
    assert time.perf_counter() - start < 2
    assert len(demos.transitions) == 12
    assert set(opened) == {"obs.npy", "rewards.npy", "episode_starts.npy", "actions.npy"}


def test_decompressed_size_limit(tmp_path, monkeypatch):
    path = tmp_path / "big.npz"
    path.write_bytes(bomb(100_000))  # 1.6 MB of zeros in a few KB
    assert path.stat().st_size < 100_000
    monkeypatch.setattr(demos_mod, "MAX_DEMO_BYTES", 2**20)
    with pytest.raises(DemoError, match=r"the arrays would take 2 MiB once decompressed; at most 1 MiB"):
        load_demonstrations(path, CARTPOLE, (4,))


def test_read_npz_limits_keys_and_suffixes():
    blob = bomb(100_000)
    h = npz_headers(blob)
    assert h["obs"].shape == (100_000, 4) and h["obs"].nbytes == 1_600_000 and h["obs"].compressed_size < 100_000
    with pytest.raises(NpzError, match=r"the archive: member 'obs.npy': 'obs' of shape \(100000, 4\).* 1.0 MiB"):
        read_npz(blob, max_array_bytes=2**20, max_total_bytes=2**30)
    with pytest.raises(NpzError, match=r"the arrays \['obs', 'rewards'\] would take .* the limit is 1.0 MiB"):
        read_npz(blob, ["obs", "rewards"], max_array_bytes=2**30, max_total_bytes=2**20)
    # only what is asked for is read; keys with or without '.npy', members with or without it
    small = read_npz(blob, ["rewards.npy", "episode_starts", "absent"], max_array_bytes=2**20, max_total_bytes=2**20)
    assert sorted(small) == ["episode_starts", "rewards"]
    plain = zip_of({"a": npy_bytes(np.arange(3)), "b.npy": npy_bytes(np.ones(2))})
    out = read_npz(plain, max_array_bytes=100, max_total_bytes=100)
    np.testing.assert_array_equal(out["a"], np.arange(3))
    np.testing.assert_array_equal(out["b"], np.ones(2))


def test_read_npz_round_trips_what_numpy_writes(tmp_path):
    arrays = {"f": np.asfortranarray(np.arange(12.0).reshape(3, 4)), "be": np.arange(5, dtype=">i4"),
              "scalar": np.array(3.5), "empty": np.zeros((0, 3)), "text": np.array(["ab", "c"]),
              "flags": np.array([True, False])}
    for compressed in (False, True):
        path = tmp_path / f"all-{compressed}.npz"
        (np.savez_compressed if compressed else np.savez)(path, **arrays)
        out = read_npz(path, max_array_bytes=2**20, max_total_bytes=2**20)
        assert sorted(out) == sorted(arrays)
        for k, v in arrays.items():
            assert out[k].dtype == v.dtype and out[k].shape == v.shape
            np.testing.assert_array_equal(out[k], v)
            assert out[k].flags.writeable


def test_maze_image_states_must_be_uint8_pixels(tmp_path):
    maze = get_env("maze3")
    path = tmp_path / "maze.npz"
    images = np.zeros((4, 32, 32, 3), np.uint8)
    np.savez(path, obs=images, rewards=np.zeros(4), episode_starts=np.array([1, 0, 1, 0]))
    assert load_demonstrations(path, maze, (32, 32, 3)).transitions.states.dtype == np.uint8
    np.savez(path, obs=images / 255.0, rewards=np.zeros(4), episode_starts=np.array([1, 0, 1, 0]))
    with pytest.raises(DemoError, match=r"'obs' has dtype float64; image states must be uint8 pixels \(0..255\)"):
        load_demonstrations(path, maze, (32, 32, 3))


def test_pickles_are_refused_by_the_reader_without_unpickling(tmp_path):
    marker = tmp_path / "unpickled"

    class Boom:
        def __reduce__(self):
            return (marker.touch, ())

    blob = npz({"x": np.array([Boom()], dtype=object)})
    assert npz_headers(blob)["x"].dtype == np.dtype(object)  # headers are fine to look at
    with pytest.raises(NpzError, match="member 'x.npy' holds Python objects"):
        read_npz(blob, max_array_bytes=2**20, max_total_bytes=2**20)
    assert not marker.exists()
