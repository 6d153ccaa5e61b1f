"""Settings compared over the composites' draws (``bench/compare_draws.py``): rows named
``<scenario>_draw<k>`` pool by scenario, and each draw pairs a setting's median with the
first setting's."""

from __future__ import annotations

import json

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def draws():
    return bench_module("compare_draws")


def _row(case: str, ate: list[float], oracle: list[float] | None = None) -> dict:
    row = {"case": case, "ate_mm": {"values": ate}}
    if oracle is not None:
        row["oracle_ate_mm"] = {"values": oracle}
    return row


def _write(folder, title: str, rows: list[dict]):
    folder.mkdir()
    (folder / "seeds.json").write_text(json.dumps({"meta": {"title": title}, "rows": rows}))
    return folder


def test_rows_pool_by_scenario_and_leave_the_others_out(draws):
    rows = [_row("comp_stop_start_draw4", [1.0, 2.0]), _row("comp_stop_start_draw5", [3.0]),
            _row("comp_three_boxes_val", [9.0]), {"case": "comp_x_draw4", "ate_mm": None}]
    got = draws.by_scenario(rows)
    assert got == {"comp_stop_start": {4: [1.0, 2.0], 5: [3.0]}}
    assert draws.pooled(got["comp_stop_start"]) == "2.0 [1.0-3.0]"


def test_each_draw_pairs_its_medians_and_counts_those_within_five_percent(draws):
    base = {4: [10.0, 10.0, 10.0], 5: [20.0], 6: [10.0]}
    other = {4: [10.4, 10.0, 11.0], 5: [30.0], 7: [1.0]}  # draw 7 has no partner
    assert draws.paired(base, other) == "1.27 [1.04-1.50], 1/2 within 5 %"
    assert draws.paired(base, {8: [1.0]}) == "-"


def test_the_table_compares_every_setting_with_the_first(draws, tmp_path, capsys):
    a = _write(tmp_path / "a", "off", [_row("comp_s_draw4", [10.0], [9.0]),
                                       _row("comp_s_draw5", [20.0], [9.5])])
    b = _write(tmp_path / "b", "on", [_row("comp_s_draw4", [12.0], [8.0]),
                                      _row("comp_s_draw5", [19.0], [8.5])])
    assert draws.main([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "| comp_s | 2 | - | 15.0 [10.0-20.0] | 9.2 [9.0-9.5] | 15.5 [12.0-19.0] |" in out
    assert "1.07 [0.95-1.20], 1/2 within 5 %" in out


def test_a_folder_without_results_is_one_line(draws, tmp_path, capsys):
    assert draws.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "seeds.json not found" in err and err.count("\n") == 1
    empty = _write(tmp_path / "e", "x", [_row("comp_s_val", [1.0])])
    assert draws.main([str(empty)]) == 2


@pytest.mark.parametrize("text", ["", "{not json", "[1, 2]", '{"rows": [{"ate_mm": {}}]}'])
def test_a_malformed_result_is_one_line(draws, tmp_path, capsys, text):
    (tmp_path / "seeds.json").write_text(text)
    assert draws.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "seeds.json" in err and err.count("\n") == 1


def test_the_best_peer_is_one_value_a_draw(draws):
    rows = [{"case": "comp_s_draw4", "best_peer_mm": 50.0},
            {"case": "comp_s_draw5", "best_peer_mm": 70}]
    assert draws.pooled(draws.by_scenario(rows, "best_peer_mm")["comp_s"]) == "60.0 [50.0-70.0]"


def test_a_figure_without_per_seed_values_is_left_out(draws):
    rows = [{"case": "comp_s_draw4", "ate_mm": {"median": 3.0}},
            {"case": "comp_s_draw5", "ate_mm": [1.0]}, _row("comp_s_draw6", [2.0])]
    assert draws.by_scenario(rows) == {"comp_s": {6: [2.0]}}
