import numpy as np
import pytest

from compass.io.lines import LineDecoder, checksum, format_line
from compass.sim.device import PtyDevice, default_model, simulate_device

CHANNELS = ("mx", "my", "mz")


def decode(*chunks, channels=CHANNELS):
    d = LineDecoder(channels)
    out = []
    for c in chunks:
        out += d.feed(c)
    return d, out


def test_crlf_lone_cr_spaces_and_split_chunks():
    d, out = decode(b"t_s , mx,my, mz\r\n0.0, 1,2 ,3\r", b"\n0.01,4,5", b",6\r0.02,7,8,9\n")
    assert [s.raw.tolist() for s in out] == [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert [s.t_s for s in out] == [0.0, 0.01, 0.02]
    assert out[0].accel is None and out[0].gyro is None and out[0].seq is None
    assert d.stats.dropped == 0 and d.stats.headers == 1


def test_columns_in_any_order_mapped_to_calibration_order():
    _, out = decode(b"mz,gx,gy,gz,ax,ay,az,my,mx,seq,temp_c\n3,0.1,0.2,0.3,0,0,9.8,2,1,7,21.5\n")
    s = out[0]
    assert s.raw.tolist() == [1, 2, 3] and s.gyro.tolist() == [0.1, 0.2, 0.3] and s.accel.tolist() == [0, 0, 9.8]
    assert s.seq == 7 and s.temp_c == 21.5 and s.t_s is None


def test_missing_optional_cells_and_incomplete_groups():
    d, out = decode(b"t_s,mx,my,mz,ax,ay,az,gx,gy\n,1,2,3,,,,0.1,0.2\n0.5,1,2,3,0,0,1,,\n0.6,1,2,3,0,,1,,\n")
    assert out[0].t_s is None and out[0].accel is None
    assert out[1].accel.tolist() == [0, 0, 1]
    assert all(s.gyro is None for s in out)  # gx,gy without gz: ignored, said so in the header event
    assert d.stats.garbage == 1  # a partly empty accelerometer group
    assert any("ignoring gx,gy" in text for _, text in d.drain_events())


def test_garbage_partial_unheaded_comments_counted_never_raised():
    rng = np.random.default_rng(0)
    noise = bytes(rng.integers(0, 256, 300, dtype=np.uint8)).replace(b"\n", b"").replace(b"\r", b"")
    d, out = decode(b"1,2,3\n", b"# module v1.2\n", b"mx,my,mz\n", b"1,2\n", b"1,2,3,4\n", b"1,x,3\n",
                    b"\xff\xfe1,2,3\n", b"1,2,nan\n", noise + b"\n", b"4,5,6\n")
    assert [s.raw.tolist() for s in out] == [[4, 5, 6]]
    s = d.stats
    assert (s.unheaded, s.comments, s.partial, s.garbage, s.invalid) == (1, 1, 1, 4, 1)  # nan: invalid
    assert s.dropped == 7


def test_overlong_line_without_terminator_is_dropped():
    d, out = decode(b"mx,my,mz\n", b"7" * 50_000, b"\n1,2,3\n")
    assert len(out) == 1 and d.stats.garbage == 1


def test_checksums_verified_and_required_after_a_checksummed_header():
    good = format_line([1, 2, 3])
    bad = good.replace(b"1,2", b"1,9")
    d, out = decode(format_line(CHANNELS), good, bad, b"1,2,3\r\n", format_line([4, 5, 6]))
    assert [s.raw.tolist() for s in out] == [[1, 2, 3], [4, 5, 6]]
    assert d.stats.garbage == 1 and d.stats.partial == 1
    assert checksum(b"GPGGA,1") == checksum(b"1,GPGGA")


def test_seq_gaps_counted_once_with_partial_lines():
    d, _ = decode(b"seq,mx,my,mz\n1,1,2,3\n2,1,2\n3,1,2,3\n6,1,2,3\n")
    assert d.stats.partial == 1 and d.stats.lost == 2 and d.stats.dropped == 3


def test_each_sample_carries_the_samples_lost_just_before_it():
    """A broken line and a seq gap are lost samples in their place: seq 2 cut short and 4-5 missing count one before
    seq 3 and two before seq 6 (a broken line inside a gap counted once); without seq, each line of a sample that
    could not be used counts one."""
    _, out = decode(b"seq,mx,my,mz\n1,1,2,3\n2,1,2\n3,1,2,3\n", b"4,1,2,3,4\n6,1,2,3\n7,1,2,3\n")
    assert [(s.seq, s.lost_before) for s in out] == [(1, 0), (3, 1), (6, 2), (7, 0)]
    _, out = decode(b"mx,my,mz\n1,2,3\n1,2\nx,y,z,w\n1,2,3\n# a comment\n1,2,3\n")
    assert [s.lost_before for s in out] == [0, 2, 0]
    # with seq the counter tells: a line of noise between two seqs in a row is no lost sample, a line broken in two
    # one, a repeat and lines without a usable header stand for the slots they leave
    _, out = decode(b"seq,mx,my,mz\n1,1,2,3\n\x01zz\n2,1,2,3\n3,1\n,2,3\n4,1,2,3\n4,1,2,3\n6,1,2,3\n")
    assert [(s.seq, s.lost_before) for s in out] == [(1, 0), (2, 0), (4, 1), (6, 1)]


def test_header_without_a_channel_stops_samples_until_a_good_one():
    d, out = decode(b"mx,my,mz\n1,2,3\n", b"mx,my,ax,ay,az\n1,2,3,4,5\n", b"mx,my,mz\n7,8,9\n")
    assert len(out) == 2 and d.stats.unheaded == 1
    assert any(level == "warn" and "lacks channel(s) mz" in text for level, text in d.drain_events())


def test_an_overlong_line_counts_once_however_it_is_chunked():
    """16.9: one 1 MB line arriving in 64 KiB reads was counted as ~500 garbage lines."""
    line = b"7," * (1 << 19) + b"\n"
    chunks = [b"mx,my,mz\n1,2,3\n"] + [line[k:k + 65536] for k in range(0, len(line), 65536)] + [b"4,5,6\n"]
    d, out = decode(*chunks)
    assert [s.raw.tolist() for s in out] == [[1, 2, 3], [4, 5, 6]]
    assert d.stats.garbage == 1 and d.stats.dropped == 1


def test_a_header_missing_a_channel_counts_its_samples_once():
    """16.9: the samples under such a header were counted both as header-less and as a seq gap."""
    good = b"seq,mx,my,mz\n" + b"".join(b"%d,1,2,3\n" % i for i in range(10))
    lacking = b"seq,mx,my\n" + b"".join(b"%d,1,2\n" % i for i in range(10, 20))
    d, out = decode(good, lacking, good.replace(b"0,1,2,3", b"X").replace(b"X", b"20,1,2,3"))
    s = d.stats
    assert (s.unheaded, s.lost, s.garbage, s.rejected_headers) == (10, 0, 0, 1)
    assert s.dropped == 10 and d.mismatch is None  # one such header may be a mangled line


def test_the_same_header_lacking_a_channel_twice_is_a_mismatch():
    d, _ = decode(b"t_s,mx,my\n0,1,2\n", b"t_s,mx,my\n0.1,1,2\n")
    assert d.mismatch == (("t_s", "mx", "my"), ("mz",)) and d.stats.garbage == 0


def test_repeated_seq_is_skipped_and_counted():
    d, out = decode(b"seq,mx,my,mz\n1,1,2,3\n2,1,2,3\n2,1,2,3\n3,1,2,3\n")
    assert [s.seq for s in out] == [1, 2, 3] and d.stats.repeated == 1 and d.stats.lost == 0


def test_a_seq_gap_across_a_reconnect_is_lost_in_transit():
    """16.9: a 2 s outage at 100 Hz (the module unplugged) was reported as 'lost in transit 0'."""
    before = b"seq,mx,my,mz\n" + b"".join(b"%d,1,2,3\n" % i for i in range(100))
    after = b"2,3\nseq,mx,my,mz\n" + b"".join(b"%d,1,2,3\n" % i for i in range(303, 310))
    d = LineDecoder(CHANNELS)
    d.feed(before)
    d.resync()
    d.feed(after)
    assert d.stats.partial == 1 and d.stats.lost == 202  # the cut fragment is one of the 203
    assert d.stats.dropped == 203


def test_a_t_s_gap_counts_lost_samples_when_there_is_no_seq():
    rate = 100.0
    t = np.r_[np.arange(100), np.arange(303, 320)] / rate
    d, out = decode(b"t_s,mx,my,mz\n" + b"".join(b"%.2f,1,2,3\n" % x for x in t))
    assert len(out) == len(t) and d.stats.lost == 203


def test_a_module_restarting_its_counter_loses_nothing():
    d, out = decode(b"seq,mx,my,mz\n7,1,2,3\n8,1,2,3\n0,1,2,3\n1,1,2,3\n")
    assert len(out) == 4 and d.stats.lost == 0 and d.stats.repeated == 0


def test_resync_drops_the_fragment_after_a_reconnect():
    d = LineDecoder(CHANNELS)
    d.feed(b"mx,my,mz\n1,2,3\n4,5")
    d.resync()
    assert d.feed(b",6\n7,8,9\n")[0].raw.tolist() == [7, 8, 9]
    assert d.stats.partial == 2  # the buffered start and the orphaned end of the cut line


def test_device_lines_decode_to_the_simulated_values():
    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    samples = simulate_device(model, np.arange(20) / 100.0, seed=1)
    d, out = decode(device._header + b"".join(device._lines(samples, 0)), channels=model.channels)
    assert len(out) == 20 and d.stats.dropped == 0
    raw = np.array([s.raw for s in out])
    np.testing.assert_allclose(raw, samples.raw, rtol=1e-6)  # %.7g
    np.testing.assert_allclose(np.array([s.gyro for s in out]), samples.gyro, atol=5e-6)
    assert [s.seq for s in out] == list(range(20))


@pytest.mark.parametrize("rate", [0.0, -5.0])
def test_device_rejects_a_bad_rate(rate):
    with pytest.raises(ValueError, match="rate must be positive"):
        PtyDevice(default_model(), rate_hz=rate)
