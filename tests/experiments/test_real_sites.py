"""The real-sites experiment (experiments/real_sites.py): its scaled copies of the benchmark map."""
import numpy as np

from experiments import real_sites
from jaxplan.transport import read_movingai_map


def test_a_scaled_map_draws_every_map_cell_as_a_square_of_cells(tmp_path):
    original = read_movingai_map(real_sites.MAP)
    scaled = read_movingai_map(real_sites.scaled_map(real_sites.MAP, 3, tmp_path))
    assert original.shape == (32, 32) and scaled.shape == (96, 96)
    np.testing.assert_array_equal(scaled[::3, ::3], original)
    np.testing.assert_array_equal(scaled, np.kron(original, np.ones((3, 3), bool)))
