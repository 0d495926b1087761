"""tipbot_fw.gains: validation with messages naming file and field, conversion to SI, hashing."""
import hashlib
import json
import re

import numpy as np
import pytest

import fw_support as S
from tipbot_fw.gains import GainsError, gains_from_dict, load_gains
from conftest import PAPER_GAINS, PHYSICAL_GAINS
from tipbot_fw import vocabulary



def doc_with(**changes):
    doc = S.gains_doc()
    for key, value in changes.items():
        if value is None:
            del doc[key]
        else:
            doc[key] = value
    return doc


def refused(tmp_path, doc, message, expected_ts_s=None):
    path = S.write_json(tmp_path / 'g.json', doc)
    with pytest.raises(GainsError, match='^' + re.escape(path) + ': ' + message):
        load_gains(path, expected_ts_s)


def test_valid_file_loads_with_hash_of_its_bytes(tmp_path):
    path = S.write_json(tmp_path / 'g.json', S.gains_doc())
    g = load_gains(path)
    with open(path, 'rb') as f:
        assert g.sha256 == hashlib.sha256(f.read()).hexdigest()
    assert g.ts_s == 0.005 and g.model_variant == 'physical' and g.u_max_v == 7.6
    assert g.closed_loop_spectral_radius < 1 and abs(g.detector_spectral_radius - 0.2) < 1e-9
    np.testing.assert_array_equal(g.A, np.array(S.gains_doc()['A']))


def test_wrong_shape(tmp_path):
    K = np.array(S.gains_doc()['K'])[[0, 1, 3, 4], :]
    refused(tmp_path, doc_with(K=K.tolist()), 'field K has shape 4x10, expected 5x10$')


def test_ragged_matrix(tmp_path):
    A = S.gains_doc()['A']
    A[3] = A[3][:9]
    refused(tmp_path, doc_with(A=A), r'field A has rows of different lengths \[9, 10\]')


def test_missing_key(tmp_path):
    refused(tmp_path, doc_with(G_w=None), 'field G_w is missing')


def test_nan_and_inf(tmp_path):
    L1 = S.gains_doc()['L1']
    L1[3][4] = float('nan')
    refused(tmp_path, doc_with(L1=L1), r'field L1\[3\]\[4\] is NaN, not a finite number')
    refused(tmp_path, doc_with(u_max_v=float('inf')), 'field u_max_v is Infinity, not a finite number')


@pytest.mark.parametrize('where', ['B', 'kalman.L'])
def test_an_entry_whose_products_overflow_is_refused_in_one_line(tmp_path, where):
    # 1e308 is finite, but A - B K or (I - L C) A overflow: refused by the entry's bound, named
    doc = S.gains_doc()
    block = doc['kalman'] if where == 'kalman.L' else doc
    block[where.split('.')[-1]][0][0] = 1e308
    with np.errstate(all='raise'):      # and not a warning on the way
        refused(tmp_path, doc, r'field {} has an entry of 1e\+308 \(in SI\), beyond'.format(re.escape(where)))


def test_non_number_entry(tmp_path):
    B = S.gains_doc()['B']
    B[0][0] = '1.0'
    refused(tmp_path, doc_with(B=B), r"field B entry \[0\]\[0\] is '1.0', not a number")


def test_unknown_schema_version(tmp_path):
    refused(tmp_path, doc_with(schema_version=1), 'field schema_version is 1, this firmware reads only 2')


def test_unknown_units(tmp_path):
    units = list(vocabulary.STATE_UNITS)
    units[0] = 'mm'
    refused(tmp_path, doc_with(state_units=units), r"field state_units\[0\] is 'mm', expected one of cm, m")
    units = list(vocabulary.STATE_UNITS)
    units[2] = 'deg'
    refused(tmp_path, doc_with(state_units=units), r"field state_units\[2\] is 'deg', expected one of rad")
    refused(tmp_path, doc_with(input_units=['V', 'V', 'V', 'mV', 'V']), r"field input_units\[3\] is 'mV'")


def test_ts_mismatch_with_the_expected_period(tmp_path):
    refused(tmp_path, S.gains_doc(), 'field ts_s is 0.005 s, expected 0.01 s', expected_ts_s=0.01)
    path = S.write_json(tmp_path / 'ok.json', S.gains_doc())
    assert load_gains(path, expected_ts_s=0.005).ts_s == 0.005


def test_unstable_closed_loop(tmp_path):
    refused(tmp_path, doc_with(K=np.zeros((5, 10)).tolist()),
            r'field K does not stabilize A: spectral radius of A - B K is 1\.03\d* >= 1')


def test_unstable_detector(tmp_path):
    doc = S.gains_doc()
    abar = (np.eye(10) - np.array(doc['L2'])).dot(np.array(doc['A']))
    L1 = abar - 1.5 * np.eye(10)    # Abar - L1 C = 1.5 I
    refused(tmp_path, doc_with(L1=L1.tolist()),
            r'field L1 gives an unstable detector: spectral radius of Abar - L1 C is 1.500000 >= 1')


def test_claimed_spectral_radius_must_match(tmp_path):
    refused(tmp_path, doc_with(closed_loop_spectral_radius=0.5),
            r'field closed_loop_spectral_radius is 0.5 but A - B K has 0.99')


def test_structure_of_an_unactuated_link_1(tmp_path):
    K = np.array(S.gains_doc()['K'])
    K[2, 3] = 0.5
    refused(tmp_path, doc_with(K=K.tolist()), r'field K row 2 \(u_th1\) must be zero')
    B = np.array(S.gains_doc()['B'])
    B[7, 2] = 0.1
    refused(tmp_path, doc_with(B=B.tolist()), r'field B column 2 \(u_th1\) must be zero')
    refused(tmp_path, doc_with(actuated_inputs=[0, 1, 2, 3]), r'field actuated_inputs is \[0, 1, 2, 3\]')


def test_c_must_be_identity(tmp_path):
    C = np.eye(10)
    C[4, 4] = 0.0
    refused(tmp_path, doc_with(C=C.tolist()), 'field C must be the identity')


def test_not_json(tmp_path):
    p = tmp_path / 'g.json'
    p.write_text('{"A": [1, 2')
    with pytest.raises(GainsError, match=re.escape(str(p)) + ': not valid JSON'):
        load_gains(str(p))
    with pytest.raises(GainsError, match='cannot read'):
        load_gains(str(tmp_path / 'missing.json'))


def test_cm_file_converts_to_the_same_si_gains():
    si = gains_from_dict(S.gains_doc(), 'si')
    cm_doc = S.to_cm(S.gains_doc())
    # the pair really differs in the file: d rows and columns scaled by 100
    assert not np.allclose(np.array(cm_doc['K']), np.array(S.gains_doc()['K']))
    cm = gains_from_dict(cm_doc, 'cm')
    assert cm.state_units_file[0] == 'cm' and cm.model_variant == 'paper'
    for name in ('A', 'B', 'E', 'K', 'K_w', 'L1', 'L2', 'G_w', 'Q', 'R', 'C'):
        a, b = getattr(si, name), getattr(cm, name)
        assert np.allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(a).max()), name
    assert cm.closed_loop_spectral_radius == pytest.approx(si.closed_loop_spectral_radius, rel=1e-12)


def test_committed_gains_files_pass_validation():
    phys = load_gains(PHYSICAL_GAINS, expected_ts_s=0.005)
    paper = load_gains(PAPER_GAINS)
    assert phys.state_units_file[0] == 'm' and paper.state_units_file[0] == 'cm'
    # the conversion really happened: in SI the wheel displacement gain is 100x the file's
    with open(PAPER_GAINS) as f:
        K_file = np.array(json.load(f)['K'])
    np.testing.assert_allclose(paper.K[:, 0], 100.0 * K_file[:, 0])
    np.testing.assert_allclose(paper.K[:, 2], K_file[:, 2])
