"""ttball's Python bindings against an independent numpy model, physical invariants, the estimator on
a flight with known truth, and their errors."""

import pathlib

import numpy as np
import pytest

import ttball
from numpy_flight import Flight

REPO = pathlib.Path(__file__).resolve().parents[2]

# A ball from the opponent's side: over the net, a bounce on the robot's half, the hitting plane.
SERVE = np.array([1.2, 0.1, 0.25, -6.0, -0.2, 1.2, 0.0, 80.0, 0.0])
# A ball in free flight for a second, clear of the table and the net.
FREE = np.array([-3.0, 0.0, 3.0, -8.0, 0.5, 2.0, 20.0, -100.0, 30.0])


def test_predict_flies_the_model_of_the_docs():
    config = ttball.Config()
    t = ttball.predict(FREE, horizon=0.8, dt=0.01, config=config)
    assert t["t"].shape == (81,) and t["states"].shape == (81, 9)
    assert t["end"] == "horizon" and t["events"] == []
    reference = Flight(config).rk4(FREE, 0.8, 0.001)[::10]
    # ttball's 40 ms RK4 steps and their interpolation against numpy's 1 ms steps.
    assert np.abs(t["states"][:, :3] - reference[:, :3]).max() < 1e-4
    assert np.abs(t["states"][:, 3:6] - reference[:, 3:6]).max() < 1e-3
    assert np.array_equal(t["states"][0], FREE)


def test_predict_bounces_on_the_table_and_crosses_the_plane():
    t = ttball.predict(SERVE)
    kinds = [e["kind"] for e in t["events"]]
    assert kinds[:3] == ["net", "bounce", "plane"], kinds
    bounce = t["events"][1]
    # The table's restitution (table.restitution, 0.9) on the vertical velocity.
    assert bounce["after"][5] == pytest.approx(-0.9 * bounce["before"][5], rel=1e-9)
    assert bounce["before"][0] < 0  # on the robot's half
    plane = t["events"][2]
    assert plane["before"][0] == pytest.approx(-1.6, abs=1e-6)
    moved = ttball.predict(SERVE, config=ttball.Config(params={"intercept.plane_x": -1.45}))
    assert [e for e in moved["events"] if e["kind"] == "plane"][0]["before"][0] == pytest.approx(
        -1.45, abs=1e-6
    )


def test_rebound_is_a_physical_hit():
    ball = np.array([-1.6, 0.0, 0.2, -5.0, 0.0, -1.0, 0.0, 50.0, 0.0])
    r = ttball.rebound(ball, racket_velocity=[4.0, 0.0, 1.0], racket_normal=[1.0, 0.0, 0.0])
    assert r["ball"].shape == (9,)
    assert r["ball"][3] > 0  # the ball goes back toward the opponent
    assert 0 < r["restitution"] < 1
    assert 5e-4 < r["contact_time"] < 3e-3
    assert r["peak_force"] > r["mean_force"] > 0
    # Normal momentum: the ball's gain is the racket's loss at the impact point's reduced mass.
    mass = 0.0027
    ball_gain = mass * (r["ball"][3] - ball[3])
    racket_loss = r["reduced_mass"] * (4.0 - r["racket_velocity"][0])
    assert ball_gain == pytest.approx(racket_loss, rel=1e-6)
    assert ball_gain == pytest.approx(r["impulse"], rel=1e-6)


def test_plan_return_lands_on_the_target():
    ball = ttball.predict(SERVE)["events"][2]["before"]
    plan = ttball.plan_return(ball, target=[1.0, 0.3], net_clearance=0.15)
    assert plan["landing_error"] < 0.01
    landing = plan["rebound"]["return_flight"]["landing"]
    assert landing[:2] == pytest.approx([1.0, 0.3], abs=0.01)
    # The plan's racket, hit again through rebound(), gives the same return.
    again = ttball.rebound(ball, plan["racket_velocity"], plan["racket_normal"], plan["impact_offset"])
    assert np.allclose(again["ball"], plan["rebound"]["ball"])
    with pytest.raises(ttball.PlanError):
        ttball.plan_return(ball, target=[np.nan, 0.0])


def detections(rate=150.0, noise=0.001, seed=3):
    """The serve seen at `rate` Hz with `noise` m of noise per axis, to just before the plane."""
    truth = ttball.predict(SERVE, horizon=0.7, dt=1.0 / rate)
    keep = truth["t"] < 0.59
    rng = np.random.default_rng(seed)
    stamps = (1_700_000_000.0 + truth["t"][keep]) * 1e9
    positions = truth["states"][keep, :3] + rng.normal(0.0, noise, (keep.sum(), 3))
    return stamps.astype(np.int64), positions, truth


def test_the_estimator_tracks_a_flight_and_predicts_its_crossing():
    stamps, positions, truth = detections()
    estimator = ttball.Estimator()
    out = estimator.handle_many(stamps, positions)
    n = len(stamps)
    assert out["state"].shape == (n, 9) and out["covariance"].shape == (n, 9, 9)
    assert out["verdict"][:2] == ["initializing", "initializing"]
    assert out["verdict"].count("fused") > 0.9 * n
    assert len(set(out["track_id"][out["track_id"] > 0])) == 1  # one track
    # The velocity 0.1 s before the end, against the truth at that stamp.
    k = n - 15
    true_state = truth["states"][k]
    assert np.linalg.norm(out["state"][k, 3:6] - true_state[3:6]) < 0.1
    # The crossing of the plane predicted 0.1 s ahead, against where the true flight crosses.
    crossing = [e for e in truth["events"] if e["kind"] == "plane"][0]
    assert out["intercept_valid"][k]
    assert np.linalg.norm(out["intercept_state"][k, 1:3] - crossing["before"][1:3]) < 0.02
    assert estimator.counters()["tracks"] == 1
    learned = estimator.learned()
    assert set(learned) >= {"drag_scale", "magnus_scale", "restitution", "friction", "tracks"}
    a_m, a_m_sigma = learned["reynolds_exponent_a_M"]
    assert abs(a_m + 0.65) < 0.5 and 0 < a_m_sigma <= 0.3
    assert learned["reynolds_exponent_a_D"] == (-0.3, 0.0)


def test_handle_and_handle_many_agree():
    stamps, positions, _ = detections(seed=5)
    one_by_one, batch = ttball.Estimator(), ttball.Estimator()
    many = batch.handle_many(stamps, positions)
    for k, (stamp, position) in enumerate(zip(stamps, positions)):
        out = one_by_one.handle(int(stamp), position)
        assert out["verdict"] == many["verdict"][k]
        if out["estimate"] is not None:
            assert np.array_equal(out["estimate"]["state"], many["state"][k])
        if out["intercept"] is not None and out["intercept"]["valid"]:
            assert np.array_equal(out["intercept"]["state"], many["intercept_state"][k])
    assert one_by_one.estimate()["stamp"] == stamps[-1]
    flight = one_by_one.predict(horizon=0.3, dt=0.01)
    assert flight["states"].shape == (31, 9)


def test_every_configuration_key_is_reachable_and_checked():
    config = ttball.Config(REPO / "config/presets/seed_2014.yaml", {"intercept.plane_x": -1.45})
    assert config.get("intercept.plane_x") == -1.45
    assert config.get("aero.reynolds_exponents") == [0.0, 0.0]  # the preset's
    assert "plane_x: -1.45" in config.yaml()
    values = config.values()
    assert set(config.names()) <= set(values) and len(values) > 50
    assert ttball.Config().get("aero.magnus_scale") == 0.7
    with pytest.raises(ttball.ConfigError, match="did you mean `intercept.plane_x`"):
        ttball.Config(params={"intercept.plane_xx": -1.45})
    with pytest.raises(ttball.ConfigError, match="out of range"):
        ttball.Config(params={"intercept.plane_x": 5})
    with pytest.raises(ttball.ConfigError):
        ttball.Config("no/such/file.yaml")
    assert issubclass(ttball.ConfigError, ValueError)


def test_the_package_is_the_crate_s_version():
    cargo = (REPO / "python/Cargo.toml").read_text()
    assert f'version = "{ttball.__version__}"' in cargo


def test_bad_input_is_a_python_exception():
    with pytest.raises(ValueError, match="state must have 9 values"):
        ttball.predict([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="horizon"):
        ttball.predict(SERVE, horizon=-1.0)
    with pytest.raises(ttball.ImpactError, match="unit vector"):
        ttball.rebound(SERVE, [1.0, 0.0, 0.0], [2.0, 0.0, 0.0])
    estimator = ttball.Estimator()
    with pytest.raises(ValueError, match="N x 3"):
        estimator.handle_many(np.arange(4), np.zeros((3, 3)))
    # A non-finite detection is counted by reason, not raised.
    out = estimator.handle(1, [np.nan, 0.0, 0.1])
    assert out["verdict"] == "non_finite"
    assert estimator.counters()["rejected"]["non_finite"] == 1


def test_the_readme_example_runs(monkeypatch):
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Python") :]
    start = section.index("```python\n") + len("```python\n")
    example = section[start : section.index("```", start)]
    monkeypatch.chdir(REPO)
    scope = {}
    exec(compile(example, "README.md", "exec"), scope)  # noqa: S102 - the README's own code
    # Its handle_many takes a column slice of the flight (not contiguous in memory).
    assert scope["arrays"]["state"].shape == (len(scope["flight"]["t"]) - 1, 9)
    assert scope["plan"]["landing_error"] < 0.01


def test_an_announced_hit_starts_the_return_s_track_at_its_first_detection():
    stamps, positions, truth = detections(seed=7)
    estimator = ttball.Estimator()
    incoming = estimator.handle_many(stamps, positions)
    crossing = [e for e in truth["events"] if e["kind"] == "plane"][0]
    plan = ttball.plan_return(crossing["before"], target=[1.0, 0.3], net_clearance=0.15)
    impact = int(1_700_000_000 * 1e9 + crossing["t"] * 1e9)
    estimator.expect_hit(impact, plan["racket_velocity"], plan["racket_normal"], plan["impact_offset"])
    back = ttball.predict(plan["rebound"]["ball"], horizon=0.2, dt=1.0 / 150)
    first = estimator.handle(impact + int(back["t"][2] * 1e9), back["states"][2, :3])
    assert first["verdict"] == "fused", first["verdict"]
    assert first["estimate"]["track_id"] != incoming["track_id"][-1]
    assert estimator.counters()["seeded_by_hit"] == 1
