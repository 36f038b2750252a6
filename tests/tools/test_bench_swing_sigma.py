"""tools/bench_swing_sigma.py's command line: bad seed counts are refused in one line, not a traceback."""


import pytest

from tests._paths import load_tool


@pytest.fixture(scope="module")
def bench():
    return load_tool("bench_swing_sigma")


@pytest.mark.parametrize("argv, message", [(["--n", "0"], "--n: expected at least one seed, got 0"),
                                           (["--sets", "5-3"], "holds no seed"),
                                           (["--sets", "a-b"], "expected seed ranges")])
def test_no_seed_is_a_usage_error(bench, capsys, argv, message):
    with pytest.raises(SystemExit) as stop:
        bench.main(argv + ["--baseline", "none"])
    assert stop.value.code == 2
    assert message in capsys.readouterr().err
