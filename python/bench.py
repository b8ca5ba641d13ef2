"""One second of predicted flight from Python: ttball.predict against a numpy RK4 of the same model
(tests/numpy_flight.py), side by side, with how far apart their flights end.

Usage: python python/bench.py  (ttball installed: pip install ./python)
"""

import pathlib
import sys
import timeit

import numpy as np

import ttball

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent / "tests"))
from numpy_flight import Flight  # noqa: E402

# A ball in free flight for a second, clear of the table and the net.
STATE = np.array([-3.0, 0.0, 3.0, -8.0, 0.5, 2.0, 20.0, -100.0, 30.0])


def best_of(f, repeat=5):
    """The fastest of `repeat` timings of `f` [s], each over enough calls to take 0.2 s."""
    timer = timeit.Timer(f)
    number, _ = timer.autorange()
    return min(timer.repeat(repeat=repeat, number=number)) / number


def main():
    config = ttball.Config()
    flight = Flight(config)
    ours = ttball.predict(STATE, horizon=1.0, dt=0.01, config=config)
    rows = []
    for step in (0.01, 0.001):
        reference = flight.rk4(STATE, 1.0, step)
        apart = np.linalg.norm(ours["states"][-1, :3] - reference[-1, :3])
        seconds = best_of(lambda: flight.rk4(STATE, 1.0, step))
        rows.append((f"numpy RK4, {step * 1e3:g} ms steps", seconds, f"{apart * 1e3:.4f} mm"))
    seconds = best_of(lambda: ttball.predict(STATE, horizon=1.0, dt=0.01, config=config))
    rows.insert(0, ("ttball.predict, samples every 10 ms", seconds, "-"))
    print("| 1 s of flight from Python | time per call [ms] | x real time | end apart from ttball's |")
    print("|---|---|---|---|")
    for name, seconds, apart in rows:
        print(f"| {name} | {seconds * 1e3:.3f} | {1.0 / seconds:,.0f} | {apart} |")


if __name__ == "__main__":
    main()
