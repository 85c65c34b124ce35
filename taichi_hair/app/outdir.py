"""Output folders of runs: made, locked against a second process, checked before any work, and
file errors that name their file."""

import contextlib
from pathlib import Path

import numpy as np

STATE_FILE = "state.npz"
LOCK_FILE = ".lock"  # held (flock) by the run writing the folder


def make_out_dir(out_dir) -> Path:
    """The output folder with its frames/ subfolder (ValueError naming --out if it cannot be made)."""
    out = Path(out_dir)
    try:
        (out / "frames").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{out}: cannot create the output folder (--out): {err.strerror or err}") from None
    return out


def claim_out_dir(out_dir, script, *, frames=None, resume=False, usd=None):
    """The output folder, made, locked for this process and checked before any work: the lock
    (OUT/.lock, an flock released when the returned handle closes or the process dies) refuses a
    second run on the same --out; --resume refuses --frames below the frames the folder's
    checkpoint has finished (it would cut the video short); --usd refuses a folder in the way of
    the USD file. Returns (out, lock handle). ValueError naming the option otherwise."""
    out = make_out_dir(out_dir)
    lock = open(out / LOCK_FILE, "a+")
    try:
        import fcntl
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except ImportError:  # no flock on this platform: no lock
        pass
    except OSError:
        lock.close()
        raise ValueError(f"{out}: another taichi-hair run is writing to this folder (--out); "
                         f"wait for it to end or choose another --out") from None
    if usd is not None and (out / f"{Path(script).stem}.{usd}").is_dir():
        lock.close()
        raise ValueError(f"--usd: {out / f'{Path(script).stem}.{usd}'} is a folder; move it or choose another --out")
    if resume and frames is not None:
        finished = _frames_done(out)
        if finished > frames:
            lock.close()
            raise ValueError(f"--frames {frames} is fewer than the {finished} frames already finished in {out} "
                             f"(--resume would cut its video short): give --frames {finished} or more")
    return out, lock


def _frames_done(out) -> int:
    """The frame count of out's checkpoint (0 if none or unreadable: run_output.resume_point says why later)."""
    try:
        with np.load(Path(out) / STATE_FILE) as data:
            return int(data["extra_frames_done"])
    except Exception:  # no checkpoint, or a damaged one (refused with its reason by run_output.resume_point)
        return 0


@contextlib.contextmanager
def naming_file(path):
    """An OSError without a file name (a full disk in the middle of a zip or PNG write: "[Errno 28]
    No space left on device") raised again naming `path`, so the one-line CLI error says where."""
    try:
        yield
    except OSError as err:
        if err.filename is not None:
            raise
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err
