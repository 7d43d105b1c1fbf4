"""Report pictures: block averages with and without NaN, the status legend's shares."""

import numpy as np

from pipeline.report.images import shrink, status_legend


def test_shrink_averages_blocks_and_ignores_nan_only_where_there_is_nan():
    image = np.arange(6 * 8 * 2, dtype=np.float32).reshape(6, 8, 2)
    small = shrink(image, 4)
    assert small.shape == (3, 4, 2)
    np.testing.assert_allclose(small[0, 0], image[:2, :2].reshape(-1, 2).mean(axis=0))
    holes = image.copy()
    holes[0, 0] = np.nan
    holes[4:, 6:] = np.nan
    with_nan = shrink(holes, 4)
    np.testing.assert_allclose(with_nan[0, 0], np.nanmean(holes[:2, :2].reshape(-1, 2), axis=0))
    assert np.isnan(with_nan[2, 3]).all() and np.isfinite(with_nan[:2]).all()


def test_shrink_is_the_block_mean_for_any_channel_count_and_a_ragged_edge():
    rng = np.random.default_rng(3)
    for colours in (1, 3, 4, 5):
        image = rng.random((103, 157, colours), dtype=np.float32)   # 10 x 15 blocks of 10 px, 3 and 7 left over
        small = shrink(image, 16)
        blocks = image[:100, :150].reshape(10, 10, 15, 10, colours).astype(np.float64).mean(axis=(1, 3))
        assert small.shape == (10, 15, colours) and small.dtype == np.float32
        np.testing.assert_allclose(small, blocks, rtol=1e-5)


def test_status_legend_counts_every_code_but_background():
    codes = np.array([[0, 1, 1, 4], [1, 7, 0, 0]])
    colours = np.zeros((256, 3), np.uint8)
    rows = status_legend(codes, {0: "background", 1: "ok", 4: "not_converged"}, colours)
    assert [(code, name, pixels) for code, name, _, pixels, _ in rows] == [(1, "ok", 3), (4, "not_converged", 1),
                                                                         (7, "code 7", 1)]
    assert abs(sum(share for *_, share in rows) - 1) < 1e-12
