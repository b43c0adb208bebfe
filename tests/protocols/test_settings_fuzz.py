"""Random TOML to every settings file kind: always the package's user error naming the key.

Each example takes a valid file, breaks ONE key (a wrong type, an unknown key, a value out
of range, a huge/NaN/inf number, a string with control characters) and checks that loading
raises the package's ConfigError-style exception (never another exception, never a hang)
and that the message names the broken key.
"""

from __future__ import annotations

import math
import tomllib

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.analysis.errors import SettingError
from nmsid.drivers.errors import HardwareConfigError
from nmsid.protocols.config import ConfigError, load_config
from nmsid.study.config import load_study
from nmsid.study.errors import StudyConfigError

BAD_VALUES = st.one_of(
    st.just(math.nan), st.just(math.inf), st.just(-math.inf), st.just(1e308), st.just(-1e308),
    st.just(2 ** 63 - 1), st.just(-(2 ** 63)), st.just(0), st.just(-1), st.just(1e-300),
    st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=8)
    .map(lambda t: t + "\n\x1b"),
    st.booleans(), st.lists(st.integers(-3, 3), max_size=3), st.just({"x": 1}),
)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return '"' + "".join(c if c.isalnum() and c.isascii() else
                             (f"\\u{ord(c):04x}" if ord(c) <= 0xFFFF else f"\\U{ord(c):08x}")
                             for c in v) + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(v)


def _dump(tables: dict) -> str:
    """A minimal TOML writer for nested tables of scalars/lists."""
    lines, subs = [], []
    for k, v in tables.items():
        if isinstance(v, dict) and v and all(isinstance(x, dict) or True for x in v.values()) \
                and k not in _INLINE:
            subs.append((k, v))
        else:
            lines.append(f'"{k}" = {_toml_value(v)}')
    out = "\n".join(lines) + "\n"
    for name, table in subs:
        out += _dump_table(name, table)
    return out


_INLINE: set[str] = set()


def _dump_table(name, table) -> str:
    lines, subs = [f"[{name}]"], []
    for k, v in table.items():
        if isinstance(v, dict):
            subs.append((f"{name}.{k}", v))
        else:
            lines.append(f'"{k}" = {_toml_value(v)}')
    out = "\n".join(lines) + "\n"
    for n, t in subs:
        out += _dump_table(n, t)
    return out


PROTOCOL_FILE = {
    "participant": "P01", "seed": 7,
    "protocol": {"sE_levels": [0.3, 0.5], "repeats": 2, "randomisation": "blocks",
                 "steady_s": 5.0, "chirp_s": 10.0, "chirp_f0_Hz": 1.0, "chirp_f1_Hz": 10.0,
                 "rE_centre": 0.5, "rE_amplitude": 0.5, "fs_Hz": 2000.0, "carrier_Hz": 1000.0,
                 "rest_s": 60.0, "pause_policy": "finish", "input_kind": "chirp",
                 "multisine_tones": 24},
    "calibration": {"step_mA": 0.5, "hold_s": 1.0, "settle_fraction": 0.5, "baseline_s": 1.0,
                    "rest_s": 2.0, "Fmin_N": 0.5, "Fmax_N": 5.0, "ceiling_ext_mA": 16.0,
                    "ceiling_flex_mA": 16.0, "force_ceiling_N": 10.0, "confirm": False,
                    "manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                               "Ifmax_mA": 8.0}},
    "interlock": {"force_limit_N": 25.0, "stall_timeout_s": 0.1, "trip_on_overrun": True,
                  "trip_on_over_range": True, "trip_on_sensor_fault": True,
                  "estop_poll_Hz": 1000.0},
}

STUDY_FILE = {
    "sessions": ["*.h5"],
    "participants": {"S0": "P01"},
    "settings": {"gap": True, "gap_max_sessions": 0, "figures": True},
    "identification": {"lowpass_Hz": 25.0, "butter_order": 4, "iqr_k": 1.5,
                       "savgol_window": 41, "fit_fs_Hz": 200.0, "resid_lags": 25,
                       "qc_settings": {"spike_k": 8.0, "min_repeats": 2}},
}

HW_FILE = {
    "rig": {"name": "bench", "fake": True, "fake_speed": 1.0},
    "stimulator": {"kind": "stg4002", "extensor_channel": 1, "flexor_channel": 2,
                   "sync_out": 1, "ceiling_ext_mA": 16.0, "ceiling_flex_mA": 16.0},
    "acquisition": {"kind": "caio", "fs_Hz": 2000.0,
                    "caio": {"device_name": "AIO000", "range": "PM10"}},
    "sensor": {"model": "PFS080YA501G6", "extension_direction": [1.0, 0.0, 0.0],
               "sync_channel": 6, "channels": {"Fx": 0, "Fy": 1, "Fz": 2},
               "rated": {"Fx": 500.0, "Fy": 500.0, "Fz": 500.0},
               "rated_output_V": {"Fx": 10.0, "Fy": 10.0, "Fz": 10.0}},
    "estop": {"kind": "none"},
}


def _keys(d: dict, prefix=()) -> list[tuple[str, ...]]:
    out = []
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.extend(_keys(v, prefix + (k,)))
        else:
            out.append(prefix + (k,))
    return out


def _set(d: dict, path: tuple[str, ...], value) -> dict:
    import copy
    d = copy.deepcopy(d)
    cur = d
    for p in path[:-1]:
        cur = cur[p]
    cur[path[-1]] = value
    return d


def _mutation(base: dict):
    keys = _keys(base)
    bad_value = st.tuples(st.sampled_from(keys), BAD_VALUES).map(
        lambda kv: (kv[0], _set(base, kv[0], kv[1])))
    unknown = st.tuples(st.sampled_from([k[:-1] for k in keys]),
                        st.sampled_from(["typo_s", "sE_stepp", "Fmax", "colour"])).map(
        lambda t: (t[0] + (t[1],), _set(base, t[0] + (t[1],), 1.0)))
    return st.one_of(bad_value, unknown)


def _check(path, data, base, load, error_cls, tmp_path):
    f = tmp_path / "s.toml"
    text = _dump(data)
    f.write_text(text, encoding="utf-8")
    tomllib.loads(text)      # the writer's output is TOML
    try:
        load(f)
    except error_cls as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        assert str(f) in msg, msg
        dotted = ".".join(path)
        parent = ".".join(path[:-1])
        # the key, or (for a table replaced by a non-table) the table's name
        assert dotted in msg or (parent and parent in msg), (dotted, msg)
        return
    # accepted: only if the value is one the key takes (same type, in range)


@settings(max_examples=60, deadline=2000,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=_mutation(PROTOCOL_FILE))
def test_protocol_file_fuzz(case, tmp_path):
    path, data = case
    _check(path, data, PROTOCOL_FILE, load_config, ConfigError, tmp_path)


@settings(max_examples=60, deadline=2000,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=_mutation(STUDY_FILE))
def test_study_file_fuzz(case, tmp_path):
    path, data = case
    (tmp_path / "S0.h5").write_bytes(b"")

    def load(f):
        return load_study(f).identification_settings()
    _check(path, data, STUDY_FILE, load, (StudyConfigError, SettingError), tmp_path)


@settings(max_examples=60, deadline=2000,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=_mutation(HW_FILE))
def test_hw_file_fuzz(case, tmp_path):
    from nmsid.drivers.hw_config import load_hw_config
    path, data = case
    _check(path, data, HW_FILE, load_hw_config, HardwareConfigError, tmp_path)


def test_valid_files_load(tmp_path):
    from nmsid.drivers.hw_config import load_hw_config
    f = tmp_path / "p.toml"
    f.write_text(_dump(PROTOCOL_FILE))
    assert load_config(f).protocol.sE_levels == (0.3, 0.5)
    (tmp_path / "S0.h5").write_bytes(b"")
    f.write_text(_dump(STUDY_FILE))
    assert load_study(f).identification_settings().qc_settings.spike_k == 8.0
    f.write_text(_dump(HW_FILE))
    assert load_hw_config(f).stimulator.ceiling_ext_mA == 16.0


@pytest.mark.parametrize("text", ["\x00", "a = 1\na = 2\n", "[[x]]\n" * 3, "a = [" * 200])
def test_broken_toml_is_one_line(tmp_path, text):
    f = tmp_path / "p.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(f)
    assert ei.value.setting in ("(file)", "x") and "\n" not in str(ei.value)


@settings(max_examples=60, deadline=2000)
@given(cmd=st.sampled_from(["start", "confirm-calibration"]),
       key=st.sampled_from(["seed", "realtime", "Iemax_mA", "Ifmin_mA", "colour", "seed_"]),
       value=st.sampled_from(["x", "-1", "nan", "inf", "1e400", str(2 ** 63), "maybe",
                              "1e9", "\u00e9\u00e9"]))
def test_gui_script_arguments_fuzz(cmd, key, value):
    pytest.importorskip("PySide6")
    from nmsid.rig.gui.script import ScriptError, parse_script
    try:
        parse_script(f"{cmd} {key}={value}", "s.txt")
    except ScriptError as exc:
        msg = str(exc)
        assert msg.startswith(f"s.txt:1: {cmd}: {key} = ") and "\n" not in msg, msg
