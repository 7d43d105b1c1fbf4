import numpy as np
import pytest

from pipeline.core.errors import ImageFileError
from pipeline.reflectance import Geometry
from pipeline.reflectance.merl import MERL_SHAPE, read_merl, rusinkiewicz_angles, write_merl

SCALES = (1.0 / 1500, 1.15 / 1500, 1.66 / 1500)


def _coded_table():
    """Stored (unscaled) values that encode their own cell: c * 1e7 + ih * 1e4 + id * 1e2... ."""
    ih, idd, ip = np.meshgrid(*(np.arange(n) for n in MERL_SHAPE), indexing="ij")
    code = ih * 1e6 + idd * 1e3 + ip
    return np.stack([code + c * 1e9 for c in range(3)])


def _write_raw(path, stored):
    path.write_bytes(np.array(MERL_SHAPE, "<i4").tobytes() + stored.astype("<f8").tobytes())


def _geometry(theta_h, theta_d, phi_d):
    """n, l, v for given half/difference angles, built in the half-vector frame (h = z)."""
    n = np.array([-np.sin(theta_h), 0.0, np.cos(theta_h)])
    l = np.array([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)])
    v = 2 * l[2] * np.array([0.0, 0.0, 1.0]) - l
    return Geometry.from_vectors(n, l[None], view=v)


@pytest.mark.parametrize("cell", [(30, 40, 100), (0, 0, 0), (89, 5, 179), (7, 88, 60)])
def test_lookup_reads_the_right_cell_with_channel_scales(tmp_path, cell):
    path = tmp_path / "coded.binary"
    _write_raw(path, _coded_table())
    brdf = read_merl(path)
    ih, idd, ip = cell
    theta_h = ((ih + 0.5) / 90) ** 2 * np.pi / 2
    theta_d = (idd + 0.5) / 90 * np.pi / 2
    phi_d = (ip + 0.5) / 180 * np.pi
    values = brdf.evaluate(_geometry(theta_h, theta_d, phi_d))[0]
    code = ih * 1e6 + idd * 1e3 + ip
    np.testing.assert_allclose(values, [(code + c * 1e9) * SCALES[c] for c in range(3)], rtol=1e-12)


def test_angles_from_cosines():
    th, td, pd = rusinkiewicz_angles(_geometry(0.3, 0.6, 2.0))
    np.testing.assert_allclose([th[0], td[0], pd[0]], [0.3, 0.6, 2.0], atol=1e-9)


def test_negative_cells_are_unmeasured_and_round_trip(tmp_path):
    table = np.full((3,) + MERL_SHAPE, 0.02)
    table[1, 0, 0, :] = np.nan
    write_merl(tmp_path / "m.binary", table)
    back = read_merl(tmp_path / "m.binary")
    assert back.name == "m"
    np.testing.assert_allclose(back.table[np.isfinite(table)], 0.02)
    assert np.isnan(back.table[1, 0, 0]).all() and np.isfinite(back.table[0, 0, 0]).all()


def test_bad_files_are_named(tmp_path):
    bad = tmp_path / "bad.binary"
    bad.write_bytes(np.array([90, 90, 90], "<i4").tobytes())
    with pytest.raises(ImageFileError, match="bad.binary.*dimensions"):
        read_merl(bad)
    short = tmp_path / "short.binary"
    short.write_bytes(np.array(MERL_SHAPE, "<i4").tobytes() + b"\0" * 80)
    with pytest.raises(ImageFileError, match="short.binary.*truncated"):
        read_merl(short)
    with pytest.raises(ImageFileError, match="missing.binary"):
        read_merl(tmp_path / "missing.binary")
