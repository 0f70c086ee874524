"""bench/backend_agreement.py's summary of the contacts each engine finds in the same states."""

from __future__ import annotations

import benchscripts
import numpy as np
import pytest


@pytest.fixture(scope="module")
def backend_agreement():
    return benchscripts.load("backend_agreement")


def test_the_contacts_are_counted_a_state_with_the_deepest_and_the_vertical_share(
        backend_agreement):
    # Two states, four contacts: 3 cm deep and vertical, 1 cm at 45°, 5 mm and 2 mm upright
    # within 30° (cos 30° = 0.866), so three of four count as vertical.
    dist = np.array([-0.03, -0.01, -0.005, 0.002])
    up = np.array([1.0, np.cos(np.radians(45)), -0.9, 0.87])
    assert backend_agreement.contact_summary(dist, up, 2) == \
        "2.0 contacts a state, the deepest 30 mm, 75% of them within 30° of vertical"


def test_states_without_contacts_say_so(backend_agreement):
    assert backend_agreement.contact_summary(np.zeros(0), np.zeros(0), 4) == "no contacts"
