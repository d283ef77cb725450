"""The QTG spec (validation/qtg/spec.py): what it reads, and every fault refused in one line."""
import math

import pytest

from tests.validation.qtg.conftest import write_spec
from validation.core.errors import BadInputError
from validation.diagnose.fidelity import DEFAULT_TOLERANCES
from validation.qtg.spec import read_spec

HEAD = 'title = "t"\n'
TEST = '[[test]]\nid = "2.c.3.b"\nrecording = "ref_theta_1s_doublet.csv"\n'


def test_tolerances_windows_and_pass_rules_are_read_in_si(qtg_flights):
    spec = read_spec(write_spec(qtg_flights, HEAD + 'description = "d"\n' + TEST + """share = 0.9
window = [0.5, 4.0]
note = "n"
[test.outputs]
q = "2 deg/s"
theta = 0.02
u = "+-5 kt"
w = { tolerance = "10 %", window = [1, 2], share = 0.5 }
p = {}
[[test]]
id = "2.d.3.a"
recording = "ref_theta_1c_doublet.csv"
outputs = ["p", "phi"]
"""))
    assert (spec.title, spec.description, [t.id for t in spec.tests]) == ("t", "d", ["2.c.3.b", "2.d.3.a"])
    first, second = spec.tests
    assert first.note == "n" and first.recording.output_names[:2] == ("u", "w")
    checks = {c.name: c for c in first.outputs}
    assert checks["q"].tolerance.value == pytest.approx(math.radians(2))
    assert checks["q"].tolerance.as_stated == "2 deg/s"
    assert checks["theta"].tolerance.value == 0.02 and checks["theta"].tolerance.as_stated is None
    assert checks["u"].tolerance.value == pytest.approx(5 * 1852 / 3600)
    assert checks["w"].tolerance.relative and checks["w"].tolerance.value == pytest.approx(0.1)
    assert checks["w"].tolerance.half_width([0.0, -3.0, 1.0]) == pytest.approx(0.3)  # 10 % of the peak magnitude
    # The test's window and share hold unless the output's table gives its own.
    assert (checks["q"].window, checks["q"].share) == ((0.5, 4.0), 0.9)
    assert (checks["w"].window, checks["w"].share) == ((1.0, 2.0), 0.5)
    # An output without a tolerance takes its Table C2A band.
    assert checks["p"].tolerance.value == DEFAULT_TOLERANCES["p"].half_width
    assert [c.tolerance.source for c in second.outputs] == [DEFAULT_TOLERANCES["p"].source,
                                                            DEFAULT_TOLERANCES["phi"].source]
    assert all(c.window is None and c.share == 1.0 for c in second.outputs)
    assert first.recording is not second.recording and len(first.recording.time) == 501


@pytest.mark.parametrize("text, message", [
    ('title = "t"\n', "no [[test]] tables"),
    ('titel = "t"\n' + TEST + "outputs = ['q']\n", "unknown key 'titel' (did you mean 'title'?)"),
    ("title = \n", "not a TOML QTG spec"),
    ('title = ""\n' + TEST + "outputs = ['q']\n", "'title' must be a non-empty string"),
    (HEAD + '[[test]]\nrecording = "ref_theta_1s_doublet.csv"\noutputs = ["q"]\n', "test 1: 'id' must be"),
    (HEAD + TEST + "outptus = ['q']\n", "test '2.c.3.b': unknown key 'outptus' (did you mean 'outputs'?)"),
    (HEAD + TEST.replace("ref_theta_1s_doublet", "missing") + "outputs = ['q']\n",
     "recording missing.csv: no such file"),
    (HEAD + TEST + "outputs = ['qq']\n", "unknown output 'qq' (did you mean 'q'?); known: u, w, q, theta"),
    (HEAD + TEST + "outputs = []\n", "'outputs' must name the outputs"),
    (HEAD + TEST + "outputs = { q = '2 dg/s' }\n", "unknown unit 'dg/s' (did you mean 'deg/s'?)"),
    (HEAD + TEST + "outputs = { q = '1.5 deg' }\n", "'1.5 deg' is in deg, but q is in rad/s; use deg/s or rad/s"),
    (HEAD + TEST + "outputs = { q = '2' }\n", "the tolerance '2' has no unit"),
    (HEAD + TEST + "outputs = { q = 'two deg/s' }\n", "cannot read the tolerance 'two deg/s'"),
    (HEAD + TEST + "outputs = { q = -0.1 }\n", "the tolerance must be positive"),
    (HEAD + TEST + "outputs = { q = true }\n", "a tolerance is a number in rad/s"),
    (HEAD + TEST + "outputs = ['w']\n", "output 'w': no tolerance given and 14 CFR Part 60"),
    (HEAD + TEST + "outputs = { q = { tolerance = 0.1, windw = [1, 2] } }\n",
     "output 'q': unknown key 'windw' (did you mean 'window'?)"),
    (HEAD + TEST + "window = [0, 99]\noutputs = ['q']\n", "'window' [0, 99] s reaches beyond the recording (0 to 5 s)"),
    (HEAD + TEST + "window = [3, 1]\noutputs = ['q']\n", "'window' [3, 1] s must end after it starts"),
    (HEAD + TEST + "window = 3\noutputs = ['q']\n", "'window' must be [t0, t1]"),
    (HEAD + TEST + "share = 1.5\noutputs = ['q']\n", "'share' (the share of samples that must lie inside the band)"),
    (HEAD + TEST + "outputs = ['q']\n" + TEST + "outputs = ['q']\n", "test 2: id '2.c.3.b' is used twice"),
])
def test_faults_are_refused_in_one_line(qtg_flights, text, message):
    path = write_spec(qtg_flights, text, name="bad.toml")
    with pytest.raises(BadInputError) as refused:
        read_spec(path)
    assert message in str(refused.value) and "\n" not in str(refused.value)
    assert str(refused.value).startswith(str(path))


def test_a_missing_spec_is_refused(tmp_path):
    with pytest.raises(BadInputError, match="no such QTG spec"):
        read_spec(tmp_path / "none.toml")
