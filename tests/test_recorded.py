"""Tests for orchestrator.recorded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from milling_twin.orchestrator.recorded import ChannelSpec, RecordedData, RecordedDataError, load_recorded

REPO = Path(__file__).resolve().parents[1]
UMICH_01 = REPO / "scenarios" / "data" / "umich_experiment_01.csv"

GOOD = """\
t_ms,feed,power,phase,flag
0,600,1.5,Prep,0
100,1200,2.0,Layer 1 Up,1
200,1800,2.5,Layer 1 Up,true
300,600,0.5,End,False
"""


def write(tmp_path: Path, text: str, name: str = "rec.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def raises(func, *args, **kwargs) -> str:  # type: ignore[no-untyped-def]
    with pytest.raises(RecordedDataError) as info:
        func(*args, **kwargs)
    assert isinstance(info.value, ValueError)
    return str(info.value)


FEED = [ChannelSpec("feed", "feed", "mm/min")]


# ----------------------------------------------------------------------------- happy path


def test_load_converts_to_si(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    rec = load_recorded(
        path,
        [
            ChannelSpec("feed", "feed", "mm/min"),
            ChannelSpec("power", "power", "kW"),
            ChannelSpec("busy", "power", "kW", above=1.0),
            ChannelSpec("cutting", "phase", "bool", match=r"^Layer \d+ (Up|Down)$"),
            ChannelSpec("flag", "flag", "bool"),
        ],
        time_column="t_ms",
        time_unit="ms",
    )
    assert isinstance(rec, RecordedData)
    assert rec.path == path
    assert rec.time.dtype == np.float64
    np.testing.assert_allclose(rec.time, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(rec.channels["feed"], [0.01, 0.02, 0.03, 0.01])
    np.testing.assert_allclose(rec.channels["power"], [1500.0, 2000.0, 2500.0, 500.0])
    assert rec.channels["feed"].dtype == np.float64
    assert rec.channels["busy"].tolist() == [True, True, True, False]
    assert rec.channels["cutting"].tolist() == [False, True, True, False]
    assert rec.channels["flag"].tolist() == [False, True, True, False]
    assert rec.channels["cutting"].dtype == np.bool_
    assert rec.units == {
        "feed": "m/s",
        "power": "W",
        "busy": "bool",
        "cutting": "bool",
        "flag": "bool",
    }


def test_above_threshold_is_in_file_unit(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    rec = load_recorded(path, [ChannelSpec("fast", "feed", "mm/min", above=1200.0)], sample_period=1.0)
    # strictly greater: 1200 is not above 1200
    assert rec.channels["fast"].tolist() == [False, False, True, False]


def test_sample_period_time(tmp_path: Path) -> None:
    rec = load_recorded(write(tmp_path, GOOD), FEED, sample_period=0.25)
    np.testing.assert_allclose(rec.time, [0.0, 0.25, 0.5, 0.75])


def test_at_linear_and_hold(tmp_path: Path) -> None:
    rec = load_recorded(
        write(tmp_path, GOOD),
        [ChannelSpec("power", "power", "kW"), ChannelSpec("flag", "flag", "bool")],
        time_column="t_ms",
        time_unit="ms",
    )
    assert rec.at("power", 0.05) == pytest.approx(1750.0)
    assert isinstance(rec.at("power", 0.05), float)
    assert rec.at("power", 0.05, interpolation="hold") == pytest.approx(1500.0)
    assert rec.at("power", 0.1, interpolation="hold") == pytest.approx(2000.0)
    assert rec.at("power", 0.3) == pytest.approx(500.0)
    assert rec.at("power", 0.0) == pytest.approx(1500.0)
    np.testing.assert_allclose(rec.at("power", np.array([0.0, 0.15, 0.25])), [1500.0, 2250.0, 1500.0])
    np.testing.assert_allclose(
        rec.at("power", np.array([0.0, 0.15, 0.25]), interpolation="hold"), [1500.0, 2000.0, 2500.0]
    )
    # booleans always hold, even when linear is asked for
    assert rec.at("flag", 0.09) is False
    assert rec.at("flag", 0.1) is True
    assert rec.at("flag", 0.29, interpolation="linear") is True
    assert rec.at("flag", 0.3) is False
    assert rec.at("flag", np.array([0.05, 0.15])).tolist() == [False, True]


def test_at_tolerates_round_off_at_the_ends(tmp_path: Path) -> None:
    rec = load_recorded(write(tmp_path, GOOD), [ChannelSpec("power", "power", "kW")], sample_period=0.1)
    t_end = sum([0.1] * 3)  # 0.30000000000000004 > 3 * 0.1
    assert rec.at("power", t_end) == pytest.approx(500.0)


def test_at_outside_range_names_channel_and_range(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    rec = load_recorded(path, [ChannelSpec("power", "power", "kW")], time_column="t_ms", time_unit="ms")
    for t in (0.31, -0.01, np.array([0.1, 0.5]), float("nan")):
        msg = raises(rec.at, "power", t)
        assert str(path) in msg
        assert "'power'" in msg
        assert "[0.0, 0.3]" in msg
    msg = raises(rec.at, "power", 0.5)
    assert "time 0.5 s is outside" in msg


def test_at_unknown_channel_and_interpolation(tmp_path: Path) -> None:
    rec = load_recorded(write(tmp_path, GOOD), [ChannelSpec("power", "power", "kW")], sample_period=1.0)
    msg = raises(rec.at, "feed", 0.5)
    assert "'feed'" in msg and "'power'" in msg
    msg = raises(rec.at, "power", 0.5, interpolation="cubic")
    assert "'cubic'" in msg and "'power'" in msg


def test_quoted_fields_and_crlf(tmp_path: Path) -> None:
    path = tmp_path / "crlf.csv"
    path.write_bytes(b'time,"label"\r\n0.0,"a, b"\r\n0.5,"c"\r\n')
    rec = load_recorded(path, [ChannelSpec("is_a", "label", "bool", match="^a,")], time_column="time")
    assert rec.channels["is_a"].tolist() == [True, False]
    np.testing.assert_allclose(rec.time, [0.0, 0.5])


def test_umich_experiment_01() -> None:
    rec = load_recorded(
        UMICH_01,
        [
            ChannelSpec("spindle_power", "S1_OutputPower", "kW"),
            ChannelSpec("spindle_speed", "S1_ActualVelocity", "rev/s"),
            ChannelSpec("x_velocity", "X1_ActualVelocity", "mm/s"),
            ChannelSpec("cutting", "Machining_Process", "bool", match=r"^Layer"),
        ],
        sample_period=0.1,
    )
    assert rec.time.shape == (1055,)
    assert rec.channels["spindle_power"].shape == (1055,)
    np.testing.assert_allclose(np.diff(rec.time), 0.1, rtol=1e-9)
    assert rec.time[-1] == pytest.approx(105.4)
    assert rec.units["spindle_power"] == "W"
    # row index 1 of the file: S1_OutputPower = -5.27e-07 kW; last row 0.000977 kW
    assert rec.channels["spindle_power"][1] == pytest.approx(-5.27e-04)
    assert rec.channels["spindle_power"][-1] == pytest.approx(0.977)
    median_w = float(np.median(rec.channels["spindle_power"]))
    assert 150.0 < median_w < 200.0  # about 0.17 kW in the file
    assert rec.units["spindle_speed"] == "rad/s"
    assert float(np.median(rec.channels["spindle_speed"])) == pytest.approx(53.3 * 2 * np.pi)
    assert rec.channels["cutting"].sum() == 172 + 148 + 203 + 132 + 194 + 142
    assert abs(rec.channels["x_velocity"]).max() == pytest.approx(0.0449)


# ----------------------------------------------------------------------------- errors


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.csv"
    msg = raises(load_recorded, path, FEED, sample_period=0.1)
    assert str(path) in msg and "not found" in msg


def test_empty_file(tmp_path: Path) -> None:
    for text in ("", "\n  \n"):
        path = write(tmp_path, text)
        msg = raises(load_recorded, path, FEED, sample_period=0.1)
        assert msg == f"{path}: file is empty"


def test_header_missing(tmp_path: Path) -> None:
    path = write(tmp_path, "0,600,1.5\n1,1200,2.0\n")
    msg = raises(load_recorded, path, FEED, sample_period=0.1)
    assert msg.startswith(f"{path}, line 1: header missing")


def test_header_line_blank(tmp_path: Path) -> None:
    path = write(tmp_path, ",,\n1,2,3\n4,5,6\n")
    msg = raises(load_recorded, path, FEED, sample_period=0.1)
    assert msg.startswith(f"{path}, line 1: header missing")


def test_missing_column_lists_available(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, [ChannelSpec("speed", "spindle", "rpm")], sample_period=0.1)
    assert msg.startswith(f"{path}, line 1, column 'spindle': channel 'speed': column not found")
    assert "available columns: 't_ms', 'feed', 'power', 'phase', 'flag'" in msg


def test_missing_time_column(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, FEED, time_column="time")
    assert msg.startswith(f"{path}, line 1, column 'time': time column: column not found")
    assert "'t_ms'" in msg


def test_duplicate_column_in_header(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed,feed\n0,1,2\n1,3,4\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 1, column 'feed'")
    assert "2 times" in msg


def test_non_numeric_value(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0,600\n1,600\n2,6OO\n3,abc\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 4, column 'feed': non-numeric")
    assert "'6OO'" in msg
    assert "2 such cell(s)" in msg


def test_non_numeric_time(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0,600\n0.1s,600\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3, column 't': non-numeric")
    assert "'0.1s'" in msg


def test_infinite_value_is_rejected(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0,600\n1,inf\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3, column 'feed': non-numeric or non-finite value 'inf'")


def test_empty_and_nan_cells(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed,other\n0,600,1\n1,,2\n2,600,3\n3,NaN,4\n4, ,5\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3, column 'feed': empty or NaN cell")
    assert "3 such cell(s)" in msg


def test_empty_cell_in_unrequested_column_is_fine(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed,other\n0,600,\n1,600,x\n")
    rec = load_recorded(path, FEED, time_column="t")
    np.testing.assert_allclose(rec.channels["feed"], [0.01, 0.01])


def test_empty_cell_in_match_column(tmp_path: Path) -> None:
    path = write(tmp_path, "t,phase\n0,Prep\n1,\n2,End\n")
    msg = raises(load_recorded, path, [ChannelSpec("cut", "phase", "bool", match="Layer")], time_column="t")
    assert msg.startswith(f"{path}, line 3, column 'phase': empty or NaN cell")
    assert "1 such cell(s)" in msg


def test_bad_boolean_value(tmp_path: Path) -> None:
    path = write(tmp_path, "t,flag\n0,1\n1,2\n")
    msg = raises(load_recorded, path, [ChannelSpec("flag", "flag", "bool")], time_column="t")
    assert msg.startswith(f"{path}, line 3, column 'flag': value '2' is not a boolean")


def test_time_not_strictly_increasing(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0.0,1\n0.1,1\n0.2,1\n0.2,1\n0.1,1\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 5, column 't': time not strictly increasing")
    assert "'0.2' follows '0.2' (line 4)" in msg


def test_time_decreasing(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n5,1\n4,1\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3, column 't': time not strictly increasing")
    assert "'4' follows '5' (line 2)" in msg


def test_fewer_than_two_rows(tmp_path: Path) -> None:
    for text, found in (("t,feed\n", 0), ("t,feed\n0,600\n", 1)):
        path = write(tmp_path, text)
        msg = raises(load_recorded, path, FEED, time_column="t")
        assert msg.startswith(f"{path}: fewer than 2 data rows (found {found})")


def test_truncated_last_line(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed,power\n0,600,1.0\n1,600,1.0\n2,600")
    msg = raises(load_recorded, path, FEED, time_column="t")  # 'power' not even requested
    assert msg.startswith(f"{path}, line 4: truncated line: 2 fields")
    assert "header (line 1) has 3 fields" in msg


def test_too_many_fields(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0,600\n1,600,7\n2,600\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3: too many fields: 3 fields")


def test_blank_line_in_data(tmp_path: Path) -> None:
    path = write(tmp_path, "t,feed\n0,600\n\n1,600\n")
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 3: truncated line: blank line")


def test_line_numbers_count_physical_lines_with_quoted_newlines(tmp_path: Path) -> None:
    path = write(tmp_path, 't,note,feed\n0,"two\nlines",600\n1,x,600\n2,y,oops\n')
    msg = raises(load_recorded, path, FEED, time_column="t")
    assert msg.startswith(f"{path}, line 5, column 'feed': non-numeric")


def test_unknown_unit_names_channel_and_unit(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, [ChannelSpec("feed", "feed", "inch/min")], sample_period=0.1)
    assert str(path) in msg
    assert "channel 'feed'" in msg
    assert "'inch/min'" in msg
    assert "known units" in msg


def test_above_and_match_together(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    spec = ChannelSpec("x", "feed", "mm/min", above=1.0, match="a")
    msg = raises(load_recorded, path, [spec], sample_period=0.1)
    assert str(path) in msg and "channel 'x'" in msg and "at most one of 'above' and 'match'" in msg


def test_match_needs_bool_unit_and_valid_regex(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, [ChannelSpec("c", "phase", "1", match="Layer")], sample_period=0.1)
    assert "channel 'c'" in msg and "must be 'bool'" in msg
    msg = raises(load_recorded, path, [ChannelSpec("c", "phase", "bool", match="(")], sample_period=0.1)
    assert "channel 'c'" in msg and "invalid regular expression" in msg


def test_above_on_bool_unit(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, [ChannelSpec("f", "flag", "bool", above=0.5)], sample_period=0.1)
    assert "channel 'f'" in msg and "numeric unit" in msg


def test_duplicate_channel_names(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    specs = [ChannelSpec("a", "feed", "mm/min"), ChannelSpec("a", "power", "kW")]
    msg = raises(load_recorded, path, specs, sample_period=0.1)
    assert "duplicate channel name 'a'" in msg


def test_non_numeric_in_above_column(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, [ChannelSpec("p", "phase", "1", above=0.0)], sample_period=0.1)
    assert msg.startswith(f"{path}, line 2, column 'phase': non-numeric")
    assert "'Prep'" in msg


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"time_column": "t_ms", "sample_period": 0.1}],
)
def test_exactly_one_time_source(tmp_path: Path, kwargs: dict[str, object]) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, FEED, **kwargs)
    assert str(path) in msg and "exactly one of time_column and sample_period" in msg


@pytest.mark.parametrize("period", [0.0, -0.1, float("nan"), float("inf")])
def test_bad_sample_period(tmp_path: Path, period: float) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, FEED, sample_period=period)
    assert "sample_period must be a positive finite number" in msg


def test_time_unit_must_be_time(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    msg = raises(load_recorded, path, FEED, time_column="t_ms", time_unit="mm")
    assert "'mm' is not a unit of time" in msg
    msg = raises(load_recorded, path, FEED, time_column="t_ms", time_unit="fortnight")
    assert "'fortnight'" in msg


def test_recorded_data_checks_invariants(tmp_path: Path) -> None:
    with pytest.raises(RecordedDataError, match="strictly increasing"):
        RecordedData(tmp_path, np.array([0.0, 0.0]), {}, {})
    with pytest.raises(RecordedDataError, match="has shape"):
        RecordedData(tmp_path, np.array([0.0, 1.0]), {"a": np.zeros(3)}, {"a": "W"})
    with pytest.raises(RecordedDataError, match="unit 'bool'"):
        RecordedData(tmp_path, np.array([0.0, 1.0]), {"a": np.zeros(2)}, {"a": "bool"})
