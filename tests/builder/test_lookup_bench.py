"""The lookup benchmark: held-out queries, brute-force truth, the JSON figures."""

import json
import subprocess
import sys

import numpy as np
import pytest

from builder.lookup_bench import brute_force_errors, held_out_queries, label_noise
from glovedb.lookup import DatabaseIndex

pytestmark = pytest.mark.gl


def test_held_out_queries_are_deterministic_and_noisy():
    clean = held_out_queries(2, seed=5, noise=False)
    again = held_out_queries(2, seed=5, noise=False)
    noisy = held_out_queries(2, seed=5)
    for a, b, c in zip(clean, again, noisy, strict=True):
        np.testing.assert_array_equal(a[64], b[64])
        assert a[64].any() and 0.0 < np.mean(a[64] != c[64]) < 0.3


def test_label_noise_keeps_labels_valid():
    labels = np.zeros((40, 40), np.uint8)
    labels[10:30, 10:30] = 3
    noisy = label_noise(labels, np.random.default_rng(0))
    assert noisy.dtype == np.uint8 and noisy.max() <= 10
    assert 0.8 < (noisy > 0).sum() / (labels > 0).sum() < 1.2


def test_brute_force_finds_an_entry_itself(small_database):
    with DatabaseIndex(small_database) as index:
        query = index.rows(32, np.array([17]))[0]
        errors = brute_force_errors(index, query)
        assert errors.shape == (72,) and errors[17] == 0.0


def test_bench_lookup_prints_the_figures(small_database):
    result = subprocess.run(
        [sys.executable, "-m", "glove_cli", "bench", "lookup", "--db", str(small_database),
         "--cascade", "8:20,32:3", "--queries", "3", "--entries", "500", "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    for key in ("entries", "cascade", "latency_ms", "queries_per_s", "recall_top1",
                "mean_rank_true_nn", "rss_mb"):  # fmt: skip
        assert key in figures
    assert figures["entries"] == 500 and figures["latency_ms"]["median"] > 0
    assert 1.0 <= figures["mean_rank_true_nn"] <= 4.0
    # The memory reference: the 8x8 stage of 500 entries is 500 x 16 uint16 codes.
    assert figures["first_stage_mb"] == 500 * 16 * 2 / 1e6
    assert figures["first_stage_read_ms"] > 0


def test_memory_read_reads_the_whole_array():
    from builder.lookup_bench import memory_read_ms

    assert memory_read_ms(np.ones((1000, 16), np.uint16)) > 0


def test_bench_lookup_refuses_no_entries(small_database, capsys):
    from glove_cli.main import main

    argv = ["bench", "lookup", "--db", str(small_database), "--entries", "0"]
    assert main(argv) == 2
    assert "--entries must be at least 1" in capsys.readouterr().err


def test_bench_lookup_reports_a_first_stage_of_lists(small_database, capsys):
    from glove_cli.main import main

    argv = ["bench", "lookup", "--db", str(small_database), "--cascade", "8:20,32:3",
            "--queries", "3", "--first-stage", "lists", "--json"]  # fmt: skip
    assert main(argv) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["first_stage"] == "lists" and figures["scanned_images"] == 72
    assert 1 < figures["lists"] < 72 and figures["probe_share"] == 0.12
    assert 0.0 <= figures["recall_top1_vs_exhaustive"] <= 1.0


def test_bench_lookup_times_another_cascade_alternately(small_database, capsys):
    from glove_cli.main import main

    argv = ["bench", "lookup", "--db", str(small_database), "--cascade", "8:20,32:3",
            "--queries", "4", "--against", "8:20,32:3", "--json"]  # fmt: skip
    assert main(argv) == 0
    paired = json.loads(capsys.readouterr().out)["against"]
    assert paired["cascade"] == "8:20,32:3" and paired["same_top1"] == 1.0  # itself
    assert paired["median_ms"] > 0 and paired["own_median_ms"] > 0 and paired["read_ms_median"] > 0
    argv[-3:] = ["--against", "8:72,32:3"]  # and printed, not as JSON
    assert main(argv) == 0
    assert "against            8:72,32:3, the two alternating" in capsys.readouterr().out
    argv[-1] = "8:20,48:3"  # no 48 x 48 images in the file
    assert main(argv) == 2
    assert "48" in capsys.readouterr().err
