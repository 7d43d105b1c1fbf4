"""Light files of every supported format, each written here, and each refusal."""

import cv2
import numpy as np
import pytest
from scipy.io import savemat

from pipeline.core.errors import InputError
from pipeline.core.lightsio import LightSet, flag_behind, read_intensities, read_lights

DIRS = np.array([[0.1, 0.2, 0.97], [-0.3, 0.1, 0.95], [0.0, -0.4, 0.92], [0.5, 0.5, 0.7], [-0.2, -0.2, 0.96]])
UNIT = DIRS / np.linalg.norm(DIRS, axis=1, keepdims=True)
RGB = np.array([[1.0, 0.9, 0.8], [1.1, 1.0, 0.9], [0.9, 0.9, 1.0], [1.2, 1.1, 1.0], [1.0, 1.0, 1.0]])


def test_text_with_intensity_columns(tmp_path):
    path = tmp_path / "l.txt"
    path.write_text("".join(f"{x} {y} {z} {i}\n" for (x, y, z), i in zip(DIRS, RGB[:, 0])))
    lights = read_lights(path)
    np.testing.assert_allclose(lights.directions, UNIT)
    np.testing.assert_allclose(lights.intensities, RGB[:, :1])
    path.write_text("5\n" + "".join(" ".join(map(str, [*d, *i])) + "\n" for d, i in zip(DIRS, RGB)))
    np.testing.assert_allclose(read_lights(path).intensities, RGB)


def test_text_lights_as_columns_and_ambiguous_tables(tmp_path):
    path = tmp_path / "l.txt"
    many = np.vstack([DIRS] * 2)   # 10 lights as 3 rows of 10 columns (PSBox, MATLAB)
    path.write_text("\n".join(" ".join(map(str, row)) for row in many.T))
    assert len(read_lights(path)) == 10
    # 3 rows of 4: 3 lights with an intensity each, or 4 lights as columns: the frames decide
    table = np.array([[0.1, 0.2, 0.97, 1.0], [0.3, 0.1, 0.95, 2.0], [0.0, 0.4, 0.92, 3.0]])
    path.write_text("\n".join(" ".join(map(str, row)) for row in table))
    assert len(read_lights(path, count=3)) == 3 and len(read_lights(path, count=4)) == 4
    assert len(read_lights(path)) == 3   # one light per row unless told


def test_npy_npz_and_mat_files(tmp_path):
    np.save(tmp_path / "l.npy", DIRS)
    np.testing.assert_allclose(read_lights(tmp_path / "l.npy").directions, UNIT)
    np.savez(tmp_path / "l.npz", L=DIRS, I=RGB)
    with pytest.raises(InputError, match=r"l\.npz: holds 2 arrays \(L 5x3, I 5x3\); name the one .*l\.npz:L"):
        read_lights(tmp_path / "l.npz")
    np.testing.assert_allclose(read_lights(f"{tmp_path / 'l.npz'}:L").directions, UNIT)
    np.testing.assert_allclose(read_intensities(f"{tmp_path / 'l.npz'}:I", 5), RGB)
    savemat(tmp_path / "one.mat", {"S": DIRS})
    np.testing.assert_allclose(read_lights(tmp_path / "one.mat").directions, UNIT)
    savemat(tmp_path / "two.mat", {"S": DIRS, "mask": np.ones((4, 4))})
    np.testing.assert_allclose(read_lights(tmp_path / "two.mat").directions, UNIT)   # the one light table
    savemat(tmp_path / "three.mat", {"S": DIRS, "T": DIRS})
    with pytest.raises(InputError, match=r"three\.mat: holds 2 numeric variables \(S 5x3, T 5x3\)"):
        read_lights(tmp_path / "three.mat")
    with pytest.raises(InputError, match=r"no numeric variable 'Q'; it holds S 5x3, T 5x3"):
        read_lights(f"{tmp_path / 'three.mat'}:Q")


def test_opencv_filestorage_matrices(tmp_path):
    for name in ("l.yml", "l.xml"):
        storage = cv2.FileStorage(str(tmp_path / name), cv2.FILE_STORAGE_WRITE)
        storage.write("Lights", DIRS.astype(np.float32))
        storage.release()
        assert (tmp_path / name).read_text().startswith(("%YAML", "<?xml"))
        np.testing.assert_allclose(read_lights(tmp_path / name).directions, UNIT, atol=1e-6)
    storage = cv2.FileStorage(str(tmp_path / "two.yml"), cv2.FILE_STORAGE_WRITE)
    storage.write("L", DIRS)
    storage.write("I", RGB)
    storage.release()
    with pytest.raises(InputError, match="holds 2 matrices"):
        read_lights(tmp_path / "two.yml")
    np.testing.assert_allclose(read_lights(f"{tmp_path / 'two.yml'}:L").directions, UNIT)


@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR", b"hello world\nthis is not a light file\n",
                                     b"MATLAB 7.3 MAT-file" + b" " * 493 + b"\x89HDF\r\n\x1a\n"])
def test_unknown_formats_get_one_line_listing_the_supported_ones(tmp_path, content):
    path = tmp_path / "lights.dat"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_lights(path)
    message = str(info.value)
    assert "\n" not in message and "\\x" not in message
    assert ("it reads psrig lights.yaml, RTI .lp" in message and "OpenCV FileStorage" in message) \
        or "v7.3" in message


def test_a_json_or_yaml_file_of_another_shape_is_named_as_no_light_file(tmp_path):
    path = tmp_path / "lights.json"
    path.write_text('{"lights": [[0, 0, 1], [0.5, 0, 0.86], [0, 0.5, 0.86]]}')
    with pytest.raises(InputError, match="not a light file psrig reads .*keys lights, no 'directions'.*OpenCV"):
        read_lights(path)


def test_lp_names_are_kept_and_paths_stripped(tmp_path):
    path = tmp_path / "l.lp"
    path.write_text("2\nC:\\data\\img 1.png 0 0 1\n/abs/img2.png 0.5 0 0.8\n")
    lights = read_lights(path)
    assert lights.filenames == ["C:\\data\\img 1.png", "/abs/img2.png"]


def test_intensities_checked(tmp_path):
    path = tmp_path / "i.txt"
    path.write_text("1 1 1\n2 2 2\n")
    with pytest.raises(InputError, match=r"expected 5 rows of 1 or 3 values"):
        read_intensities(path, 5)
    path.write_text("1\n2\n-1\n1\n1\n")
    with pytest.raises(InputError, match="light 2 has an intensity that is not a positive number"):
        read_intensities(path, 5)


def test_lights_behind_the_surface_are_flagged_and_a_flipped_file_refused():
    lights = LightSet(np.vstack([DIRS, [[0.3, 0.1, -0.2]]]))
    assert flag_behind(lights) == [5] and "z = -0.535 <= 0" in lights.flags[5]
    with pytest.raises(InputError, match=r"5 of 5 lights have z <= 0 .*negate z"):
        flag_behind(LightSet(DIRS * [1, 1, -1]))
