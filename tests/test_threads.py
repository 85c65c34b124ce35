"""A simulation's result does not depend on how many CPU threads Taichi runs: the step's kernels
take the strands in a mixed order spread over the threads (taichi_hair/rods/spread.py), and
each strand's step reads and writes its own rows only. Subprocesses, one per thread count."""

import hashlib
import os
import subprocess
import sys

import pytest

# tight elliptic curls on a shaking head in gusty wind: contacts with the head, neck and body,
# friction, the quasistatic twist; 30 ms of it, the positions hashed
SCRIPT = """
import hashlib
import numpy as np
import taichi_hair as th
from taichi_hair.runtime import init
init(precision="float32")
head = th.Head.default()
groom = th.scalp_groom(head.model, 48, style="curly", length=0.2, n_nodes=24, curl_radius=0.004,
                       curl_pitch=0.012, collider=head.distance_field(), seed=2)
scene = th.Scene(groom=groom, head=head, material=th.Material(ellipticity=4.0),
                 motion=th.Shake(amplitude_deg=40, frequency_hz=2.0),
                 wind=th.Wind(velocity=(2.5, 0.0, 0.0), gust_amplitude=0.6, turbulence=0.8, seed=4),
                 drag=5e-4)
sim = th.Simulator.from_scene(scene, dt=1e-3)
sim.step(30)
x = sim.positions()
assert np.isfinite(x).all()
print(hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest())
"""


def run_with_threads(threads: int) -> str:
    env = dict(os.environ, TI_CPU_MAX_NUM_THREADS=str(threads))
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.slow
def test_positions_do_not_depend_on_the_thread_count():
    digests = {threads: run_with_threads(threads) for threads in (1, 2)}
    assert len(set(digests.values())) == 1, digests
    assert len(digests[1]) == len(hashlib.sha256().hexdigest())
