"""A DMD in a bench file: the `dmd` kind validates, gets its simulated twin, opens on the
virtual bench and shares its clock."""

from __future__ import annotations

import pytest

from instrument.cli import main
from instrument.config import BenchConfigError, default_bench, to_toml
from instrument.devices.bench_setup import parse_bench
from instrument.devices.virtual_bench import VirtualBench

DMD = '''
[[devices]]
id = "dmd"
kind = "dmd"
driver = "dlp-lightcrafter4500"

[devices.params]
serial_number = "LC4500-0001"
'''


def test_dmd_device_in_a_bench_file(tmp_path, capsys):
    text = to_toml(default_bench()) + DMD
    path = tmp_path / "bench.toml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 0
    assert "1 dmd" in capsys.readouterr().out
    twin = parse_bench(text, simulate=True).device("dmd")
    assert (twin.kind, twin.driver, twin.params) == ("dmd", "simulated-dmd", {})
    bench = VirtualBench(parse_bench(text)).open()
    try:
        dmd = bench.devices["dmd"]
        dmd.load_sequence([{"image": 0, "bit": b} for b in range(2)])
        dmd.start()
        assert dmd.clock is bench.clock and dmd.running
    finally:
        bench.close()


def test_unknown_kind_names_dmd_among_the_kinds():
    text = to_toml(default_bench()) + DMD.replace('kind = "dmd"', 'kind = "projector"')
    with pytest.raises(BenchConfigError, match="'dmd'"):
        parse_bench(text)
