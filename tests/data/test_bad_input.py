"""Bad input: one-line DataError naming the file, the row or column and the fix; exit code 2;
input files are never modified."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from smcbayes.cli import main
from smcbayes.data.dataset import load_dataset
from smcbayes.data.readers.csv import read_csv
from smcbayes.data.readers.moldflow import read_moldflow
from smcbayes.data.readers.press import read_press
from smcbayes.errors import DataError

GOOD = "time_s,force_kN\n0,0\n1,100\n2,300\n"

CSV_CASES = {
    # name: (file text, words the message must contain)
    "empty": ("", ["file is empty"]),
    "header_only": ("time_s,force_kN\n", ["no data rows"]),
    "missing_column": ("time_s,force\n0,0\n1,1\n", ["missing column 'force_kN'", "data.force_column"]),
    "non_numeric": ("time_s,force_kN\n0,0\n1,abc\n2,3\n",
                    ["row 3", "column 'force_kN'", "'abc'", "fix or remove"]),
    "nan": ("time_s,force_kN\n0,0\n1,nan\n2,3\n", ["row 3", "column 'force_kN'", "NaN", "remove the row"]),
    "duplicate_time": ("time_s,force_kN\n0,0\n1,1\n1,2\n",
                       ["row 4", "column 'time_s'", "duplicate", "sort or de-duplicate"]),
    "decreasing_time": ("time_s,force_kN\n0,0\n2,1\n1,2\n", ["row 4", "decreasing", "sort or de-duplicate"]),
    "one_row": ("time_s,force_kN\n0,0\n", ["at least 2"]),
}


def _check(err: DataError, path: Path, words: list[str]) -> None:
    msg = str(err)
    assert "\n" not in msg and str(path) in msg, msg
    for w in words:
        assert w in msg, (w, msg)


@pytest.mark.parametrize("case", sorted(CSV_CASES))
def test_csv_reader_errors(tmp_path: Path, case: str) -> None:
    text, words = CSV_CASES[case]
    p = tmp_path / f"{case}.csv"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(DataError) as info:
        read_csv(p, "force_kN", "force")
    _check(info.value, p, words)


def test_file_not_found_in_every_reader(tmp_path: Path) -> None:
    p = tmp_path / "nope.csv"
    for call in (lambda: read_csv(p, "force_kN", "force"), lambda: read_press(p),
                 lambda: read_moldflow(p, "force")):
        with pytest.raises(DataError) as info:
            call()
        _check(info.value, p, ["file not found", "data_dir"])


def test_press_export_errors(tmp_path: Path) -> None:
    p = tmp_path / "p.csv"
    p.write_bytes(b"")
    with pytest.raises(DataError, match="file is empty"):
        read_press(p)
    head = "Zeit;dbPr\\diIstPos;dbPr\\diIstKraftGes\r\n;mm;kN\r\n"
    p.write_bytes((head + "01.01.2024 00:00:00.000000;1,0;2,0\r\n"
                          "01.01.2024 00:00:00.500000;1,0;x\r\n").encode("utf-16-le"))
    with pytest.raises(DataError) as info:
        read_press(p)
    _check(info.value, p, ["row 4", "dbPr\\diIstKraftGes", "'x'"])
    p.write_bytes((head + "01.01.2024 00:00:00.500000;1,0;2,0\r\n"
                          "01.01.2024 00:00:00.500000;1,0;3,0\r\n").encode("utf-16-le"))
    with pytest.raises(DataError) as info:
        read_press(p)
    _check(info.value, p, ["row 4", "duplicate", "Zeit"])
    p.write_bytes("Zeit;Pos;Kraft\r\n;mm;kN\r\n".encode("utf-16-le"))
    with pytest.raises(DataError) as info:
        read_press(p)
    _check(info.value, p, ["missing column 'dbPr\\diIstKraftGes'", "data.force_column"])
    p.write_text("time_s,force_kN\n0,1\n1,2\n", encoding="utf-8")
    with pytest.raises(DataError, match="format = 'csv'"):
        read_press(p)


def test_moldflow_errors(tmp_path: Path) -> None:
    p = tmp_path / "m.xml"
    p.write_text("")
    with pytest.raises(DataError, match="file is empty"):
        read_moldflow(p, "force")
    p.write_text("<MoldflowXMLDocument><Dataset><Block>")
    with pytest.raises(DataError, match="not well-formed XML"):
        read_moldflow(p, "force")
    base = ('<MoldflowXMLDocument><Dataset><DataDescription><Name>Press force</Name>'
            '<DeptVar><Unit>N</Unit></DeptVar></DataDescription>'
            '<Block><IndpVar Value="0"/><DeptValues>1</DeptValues></Block>{}</Dataset></MoldflowXMLDocument>')
    p.write_text(base.format('<Block><IndpVar Value="1"/><DeptValues>NaN</DeptValues></Block>'))
    with pytest.raises(DataError) as info:
        read_moldflow(p, "force")
    _check(info.value, p, ["row 2", "NaN"])
    p.write_text(base.format('<Block><IndpVar Value="zero"/><DeptValues>2</DeptValues></Block>'))
    with pytest.raises(DataError) as info:
        read_moldflow(p, "force")
    _check(info.value, p, ["block 2", "IndpVar", "'zero'"])
    p.write_text(base.format('<Block><IndpVar Value="1"/></Block>'))
    with pytest.raises(DataError, match="block 2: missing <DeptValues>"):
        read_moldflow(p, "force")


def test_force_in_N_declared_as_kN(tmp_path: Path, dh) -> None:
    dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n0,0\n1,100000\n2,300000\n")
    proj = dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})])
    with pytest.raises(DataError) as info:
        load_dataset(proj)
    _check(info.value, tmp_path / "force" / "c1.csv", ["1000x the 300 kN force limit", "force_unit = 'N'"])
    proj = dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv", "force_unit": "N"})])
    assert load_dataset(proj)["c1"].force.values.max() == pytest.approx(300.0)


def test_config_pointing_at_missing_file(tmp_path: Path, dh) -> None:
    proj = dh.project(tmp_path, [dh.config(data={"force": "force/missing.csv"})])
    with pytest.raises(DataError) as info:
        load_dataset(proj)
    _check(info.value, tmp_path / "force" / "missing.csv", ["configuration 'c1'", "data.force", "--data-dir"])


def _toml(tmp_path: Path, data_file: str) -> Path:
    text = f'''data_dir = "."
[[configuration]]
id = "c1"
charge = {{ shape = "bar", coverage_pct = 50.0 }}
press = {{ speed_mm_s = 1.0, force_limit_kN = 300.0 }}
data = {{ force = "{data_file}" }}
'''
    p = tmp_path / "p.toml"
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("case", ["missing_file", "nan", "duplicate_time", "empty"])
def test_cli_exits_2_with_one_line_and_leaves_files_alone(tmp_path: Path, case: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "force.csv"
    if case != "missing_file":
        data.write_text(CSV_CASES[case][0], encoding="utf-8")
    cfg = _toml(tmp_path, "force.csv")
    before = {p: (p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
              for p in tmp_path.iterdir()}
    assert main(["evaluate", str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(data) in err and err.startswith("smcbayes evaluate: error:")
    after = {p: (p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
             for p in tmp_path.iterdir()}
    assert after == before


def test_reading_good_data_modifies_nothing(tmp_path: Path, dh) -> None:
    body = "".join(f"{t},{30 * t}\n" for t in range(11))
    f = dh.write_text(tmp_path / "force" / "c1.csv", "time_s,force_kN\n" + body)
    stamp, content = f.stat().st_mtime_ns, f.read_bytes()
    proj = dh.project(tmp_path, [dh.config(data={"force": "force/c1.csv"})],
                      preprocess={"zero_at_contact": True, "smooth_window_s": 3.0,
                                  "smooth_order": 1, "resample_dt_s": 0.1})
    load_dataset(proj)
    assert (f.stat().st_mtime_ns, f.read_bytes()) == (stamp, content)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["c1.csv", "force"]


@pytest.mark.parametrize(("encoding", "expected"), [
    ("latin-1", "not UTF-8 text (an 8-bit code page such as Latin-1 or Windows-1252?); save it as UTF-8"),
    ("utf-16", "UTF-16 text, as the press exports it; set data.format = 'press'"),
])
def test_cli_tells_a_latin1_file_from_a_press_export(tmp_path: Path, encoding: str, expected: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "force.csv"
    data.write_bytes("# Prüfung\ntime_s,force_kN\n0,1\n1,2\n".encode(encoding))
    assert main(["evaluate", str(_toml(tmp_path, "force.csv"))]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.endswith(f"{data}: {expected}"), err
