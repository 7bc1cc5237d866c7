"""Sample ids are made and read in one place."""

import pytest

from manifests import sample_ids


@pytest.mark.parametrize(("session", "index", "text"), [("calibration", 3, "cal000003"), ("dataset", 12, "img000012"),
                                                         ("dataset", 1_234_567, "img1234567")])
def test_an_id_reads_back_as_its_session_and_index(session, index, text):
    assert sample_ids.make(session, index) == text
    assert sample_ids.parse(text) == (session, index)


@pytest.mark.parametrize("text", ["img12", "frame000001", "img00001x", "", "cal-00001"])
def test_another_id_is_named(text):
    with pytest.raises(ValueError, match="is not cal or img"):
        sample_ids.parse(text)
