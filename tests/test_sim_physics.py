"""Simulator twin physics: profiles, dynamics, noise, bias, cavitation, determinism, overrides."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigtool.errors import UsageError
from rigtool.sim.physics import ThrusterTwin, pwm_thrust_n
from rigtool.thruster_profiles import PROFILES, profile_with_overrides

QUIET = {
    "speed_noise_rpm": 0,
    "current_noise_a": 0,
    "force_noise_n": 0,
    "torque_noise_nm": 0,
    "vibration_noise_frac": 0,
    "voltage_noise_v": 0,
}


def twin(name: str, seed: int = 0, depth_m: float = 1.0, **overrides: object) -> ThrusterTwin:
    """A twin of a built-in profile with some parameters overridden."""
    return ThrusterTwin(profile_with_overrides(name, overrides), seed=seed, depth_m=depth_m)


def thrust_reading(tw: ThrusterTwin, ft: np.ndarray) -> np.ndarray:
    """The thrust channel of raw sensor output, projected on the thruster axis."""
    return tw.profile.thrust_sign * ft[:, tw.profile.thrust_channel]


def run_until_event(tw: ThrusterTwin, command: float, t_max_s: float, step_s: float = 0.5) -> float:
    """Hold `command` from t=0, sampling sparsely, until the first ventilation onset or t_max_s."""
    tw.set_command(0.0, command)
    t = 0.0
    while not tw.events and t < t_max_s:
        t += step_s
        tw.sample(np.array([t]))
    return tw.events[0].t_start_s if tw.events else math.inf


def test_builtin_profiles_are_consistent_with_their_commands() -> None:
    assert set(PROFILES) == {"can-bldc", "stm32-pwm", "esc-1100-1900"}
    for p in PROFILES.values():
        tw = ThrusterTwin(p, seed=0)
        assert tw.steady_state(p.neutral) == (0.0, 0.0, p.idle_current_a)
        assert p.command_min <= p.neutral <= p.command_max
    assert PROFILES["stm32-pwm"].feedback == ()
    assert PROFILES["can-bldc"].feedback == ("speed_rpm", "current_a", "voltage_v")


def test_can_bldc_steady_state_follows_cp_and_cn() -> None:
    tw = twin("can-bldc")
    p = tw.profile
    n, f, i = tw.steady_state(78.0)
    assert n == pytest.approx(1404.0)
    assert f == pytest.approx(1.926e-5 * 1404.0**2) == pytest.approx(38.0, abs=0.1)
    n, f, i = tw.steady_state(-50.0)
    assert n == pytest.approx(-900.0)
    assert f == pytest.approx(-0.8 * 1.926e-5 * 900.0**2)
    assert i == pytest.approx(p.cn * 900.0**3 + p.idle_current_a)
    n, f, i = tw.steady_state(100.0)
    assert n == 1800.0
    assert i == pytest.approx(350.0 / 48.0, rel=0.02)
    assert tw.steady_state(150.0) == tw.steady_state(100.0)  # clipped to the range


def test_stm32_pwm_table_reproduces_the_bench_rig() -> None:
    tw = twin("stm32-pwm")
    thrust = {c: tw.steady_state(c)[1] for c in range(800)}
    assert all(thrust[c] == 0.0 for c in range(0, 207))
    assert all(thrust[c] == 0.0 for c in range(428, 446))
    assert all(thrust[c] == pytest.approx(5.0) for c in range(207, 397))
    inverted = [thrust[c] for c in range(397, 428)]
    assert all(b < a for a, b in zip(inverted, inverted[1:], strict=False))
    assert 0.1 <= thrust[427] <= 0.2
    creep = [thrust[c] for c in range(446, 451)]
    assert all(-0.16 <= f <= -0.07 for f in creep)
    assert all(b < a for a, b in zip(creep, creep[1:], strict=False))
    assert thrust[451] == pytest.approx(-0.8)
    assert thrust[450] - thrust[451] > 0.5  # break-away jump
    ramp = [thrust[c] for c in range(451, 471)]
    assert all(b < a for a, b in zip(ramp, ramp[1:], strict=False))
    assert all(thrust[c] == pytest.approx(-3.0) for c in range(470, 800))
    assert tw.steady_state(397)[0] < tw.steady_state(396)[0] == pytest.approx(3000.0)


def test_stm32_breakaway_holds_in_the_dynamic_model() -> None:
    tw = twin("stm32-pwm", **QUIET)
    tw.set_command(0.0, 451)
    assert tw.sample(np.array([5.0])).thrust_true_n[0] == pytest.approx(-0.8, rel=1e-6)
    tw.set_command(5.0, 448)
    assert tw.sample(np.array([10.0])).thrust_true_n[0] == pytest.approx(
        pwm_thrust_n(tw.profile, 448)
    )


def test_esc_deadband_and_linear_speed() -> None:
    tw = twin("esc-1100-1900")
    assert all(tw.steady_state(c) == (0.0, 0.0, 0.1) for c in range(1475, 1526))
    assert tw.steady_state(1474)[1] < 0 < tw.steady_state(1526)[1]
    assert tw.steady_state(1900)[0] == pytest.approx(3800.0)
    assert tw.steady_state(1900)[1] == pytest.approx(50.0)
    assert tw.steady_state(1100)[1] == pytest.approx(-40.0)
    assert tw.steady_state(1712.5)[0] == pytest.approx(1900.0)


def test_first_order_response_reaches_63_percent_at_tau() -> None:
    tw = twin("can-bldc", **QUIET)
    tau = tw.profile.tau_s
    tw.set_command(0.0, 50.0)
    s = tw.sample(np.array([tau, 10 * tau]))
    assert s.speed_rpm[0] / 900.0 == pytest.approx(1 - math.exp(-1))
    assert s.speed_rpm[1] == pytest.approx(900.0, rel=1e-4)


def test_speed_is_exact_however_the_time_is_split() -> None:
    times = np.linspace(0.0, 2.0, 201)
    one = twin("can-bldc", **QUIET)
    one.set_command(0.0, 80.0)
    whole = one.sample(times).speed_rpm
    many = twin("can-bldc", **QUIET)
    many.set_command(0.0, 80.0)
    pieces = np.concatenate([many.sample(chunk).speed_rpm for chunk in np.array_split(times, 17)])
    np.testing.assert_allclose(pieces, whole, rtol=1e-12)
    many.set_command(2.0, -80.0)  # reversal crosses zero and switches to cp_reverse
    s = many.sample(np.array([2.0 + 20 * many.profile.tau_s]))
    assert s.thrust_true_n[0] == pytest.approx(-0.8 * 1.926e-5 * 1440.0**2, rel=1e-4)


def test_stm32_spread_of_500_samples_matches_the_report() -> None:
    tw = twin("stm32-pwm", seed=7)
    spreads = {}
    for k, pwm in enumerate((397, 412, 460, 470)):
        tw.set_command(10.0 * k, pwm)
        f = thrust_reading(tw, tw.sample(10.0 * k + 3.0 + np.arange(500) * 0.002).ft)
        spreads[pwm] = f.max() - f.mean()
    assert spreads[397] < 0.3 and spreads[412] < 0.3
    assert 0.02 < spreads[460] < 0.09 and 0.02 < spreads[470] < 0.09


def test_current_feedback_is_noisier_than_speed_and_voltage_sags() -> None:
    tw = twin("can-bldc", seed=1)
    tw.set_command(0.0, 78.0)
    s = tw.sample(5.0 + np.arange(3000) * 1e-3)
    assert s.speed_rpm.mean() == pytest.approx(1404.0, abs=1.0)
    # as thrust estimates: f ~ n^2 and f ~ I^(2/3), so relative errors scale by 2 and 2/3
    rel_f_i = 2 / 3 * s.current_a.std() / s.current_a.mean()
    rel_f_n = 2 * s.speed_rpm.std() / s.speed_rpm.mean()
    assert 1.1 * rel_f_n < rel_f_i < 2 * rel_f_n
    assert s.voltage_v.mean() < tw.profile.supply_voltage_v - 0.5 * 0.08 * 3.6
    assert np.std(thrust_reading(tw, s.ft)) == pytest.approx(np.hypot(0.12, 0.01 * 38.0), rel=0.1)


def test_bias_drift_and_crosstalk_on_the_raw_channels() -> None:
    for name in PROFILES:
        tw = twin(name, seed=2)
        p = tw.profile
        at_start = thrust_reading(tw, tw.sample(np.arange(2000) * 1e-3).ft).mean()
        after_hour = thrust_reading(tw, tw.sample(3600.0 + np.arange(2000) * 1e-3).ft).mean()
        assert at_start == pytest.approx(p.bias_n, abs=0.02)
        assert after_hour - at_start == pytest.approx(p.drift_n_per_h, abs=0.02)
    tw = twin("can-bldc", **QUIET)
    tw.set_command(0.0, 78.0)
    s = tw.sample(np.array([5.0]))
    np.testing.assert_allclose(s.ft[0, 1:], 38.0 * np.array(tw.profile.crosstalk[1:]), rtol=1e-3)


def test_no_cavitation_deeper_than_60_cm_over_hours() -> None:
    for depth in (0.6, 0.8):
        tw = twin("can-bldc", seed=3, depth_m=depth)
        tw.set_command(0.0, 100.0)
        for k in range(1, 7201):
            tw.sample(np.array([k - 0.5, float(k)]))
        assert tw.events == []
    assert twin("stm32-pwm", depth_m=0.2).onset_rate_per_s(3000.0) == 0.0  # disabled on the bench


def test_cavitation_onset_at_20_cm_and_its_dependence_on_speed_and_depth() -> None:
    onsets = [
        run_until_event(twin("can-bldc", seed=s, depth_m=0.2), 78.0, 300.0) for s in range(60)
    ]
    assert 4.0 < np.mean(onsets) < 9.0  # domain: ~6 s at 1404 r/min
    slow = [run_until_event(twin("can-bldc", seed=s, depth_m=0.2), 40.0, 300.0) for s in range(60)]
    fast = [run_until_event(twin("can-bldc", seed=s, depth_m=0.2), 91.0, 300.0) for s in range(60)]
    deep = [run_until_event(twin("can-bldc", seed=s, depth_m=0.45), 78.0, 300.0) for s in range(60)]
    assert np.mean(fast) < np.mean(onsets) < np.mean(slow)
    assert np.mean(onsets) < np.mean(deep)
    tw = twin("can-bldc")
    rates = [tw.onset_rate_per_s(1404.0, d) for d in (0.2, 0.3, 0.45, 0.55, 0.59, 0.6)]
    assert all(b < a for a, b in zip(rates[:4], rates[1:4], strict=False)) and rates[-1] == 0.0
    assert tw.onset_rate_per_s(250.0, 0.2) == 0.0
    assert tw.onset_rate_per_s(900.0, 0.2) < tw.onset_rate_per_s(1800.0, 0.2)


def test_event_durations_shrink_with_depth() -> None:
    means = {}
    for depth in (0.3, 0.55):
        tw = twin("can-bldc", seed=4, depth_m=depth)
        tw.set_command(0.0, 78.0)
        for k in range(1, 4001):
            tw.sample(np.array([k * 0.5]))
        durations = [e.t_end_s - e.t_start_s for e in tw.events if e.t_end_s < 2000.0]
        assert len(durations) > 10
        means[depth] = np.mean(durations)
    assert 4.0 < means[0.3] < 7.5 and 0.6 < means[0.55] < 1.6


def test_a_ventilation_event_cuts_thrust_and_current_and_adds_noise() -> None:
    tw = twin("can-bldc", seed=5, depth_m=0.2)
    run_until_event(tw, 78.0, 300.0, step_s=0.1)
    ev = tw.events[0]
    assert ev.depth_m == 0.2 and ev.speed_rpm == pytest.approx(1404.0, rel=1e-3)
    assert 0.25 <= ev.drop_frac <= 0.75
    during = tw.sample(ev.t_start_s + 0.5 + np.arange(1000) * 1e-3)
    np.testing.assert_allclose(during.thrust_true_n, 38.0 * (1 - ev.drop_frac), rtol=1e-3)
    noise = thrust_reading(tw, during.ft) - during.thrust_true_n
    assert noise.std() > 1.5 * np.hypot(0.12, 0.01 * 38.0)
    steady_current = tw.steady_state(78.0)[2]
    assert during.current_a.mean() < steady_current * (1 - 0.02 * ev.drop_frac)
    stop_t = float(during.thrust_true_n.size) * 1e-3 + ev.t_start_s + 1.0
    tw.set_command(stop_t, 0.0)  # stopping the propeller ends the event
    assert ev.t_end_s == pytest.approx(stop_t + tw.profile.cav_ramp_out_s)


def test_same_seed_same_calls_give_identical_output() -> None:
    def run(seed: int) -> tuple[list[np.ndarray], list]:
        tw = twin("esc-1100-1900", seed=seed, depth_m=0.25)
        out = []
        for k, cmd in enumerate((1700, 1850, 1300, 1900)):
            tw.set_command(20.0 * k, cmd)
            for j in range(200):
                s = tw.sample(20.0 * k + 0.1 * j + np.arange(50) * 2e-3)
                out += [s.ft, s.thrust_true_n, s.speed_rpm, s.current_a, s.voltage_v]
        return out, tw.events

    a, events_a = run(11)
    b, events_b = run(11)
    c, _ = run(12)
    assert events_a and events_a == events_b
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])


def test_time_must_not_go_backwards() -> None:
    tw = twin("can-bldc")
    tw.sample(np.array([1.0, 2.0]))
    with pytest.raises(ValueError):
        tw.sample(np.array([1.5]))
    with pytest.raises(ValueError):
        tw.set_command(1.0, 10.0)


def test_overrides_change_parameters() -> None:
    p = profile_with_overrides(
        "can-bldc", {"tau_s": 0.5, "cp_forward": "2e-5", "cavitation": False}
    )
    assert (p.tau_s, p.cp_forward, p.cavitation) == (0.5, 2e-5, False)
    assert PROFILES["can-bldc"].tau_s == 0.3
    tw = ThrusterTwin(p, seed=0)
    assert tw.steady_state(100.0)[1] == pytest.approx(2e-5 * 1800.0**2)
    moved = ThrusterTwin(profile_with_overrides("stm32-pwm", {"pwm_rev_breakaway": 455}), seed=0)
    assert moved.steady_state(452)[1] > -0.2 and moved.steady_state(455)[1] == pytest.approx(-0.8)


@pytest.mark.parametrize(
    ("name", "overrides", "expected"),
    [
        ("can-bldc", {"tau": 1.0}, ["'tau'", "tau_s"]),
        ("can-bldc", {"tau_s": "fast"}, ["'tau_s'", "fast"]),
        ("can-bldc", {"thrust_channel": 1.5}, ["'thrust_channel'"]),
        ("can-bldc", {"tau_s": -1.0}, ["tau_s"]),
        ("no-such-rig", {}, ["no-such-rig", "can-bldc", "stm32-pwm", "esc-1100-1900"]),
    ],
)
def test_bad_overrides_raise_usage_error_naming_the_problem(
    name: str, overrides: dict, expected: list[str]
) -> None:
    with pytest.raises(UsageError) as info:
        profile_with_overrides(name, overrides)
    assert all(text in str(info.value) for text in expected)
