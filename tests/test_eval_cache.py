"""The store of product measurements (eval.cache): what is stored comes back byte for byte, keys change with
anything a measurement depends on, and an interrupted store is never restored."""

from pathlib import Path

from eval.cache import ENTRY, ProductCache, StoredMeasurement, code_digest, files_in


def _eval_dir(root: Path) -> Path:
    d = root / "eval"
    (d / "plots").mkdir(parents=True)
    (d / "c2c_mvs.ply").write_bytes(b"ply\x00binary distances")
    (d / "plots" / "c2c_mvs_hist.svg").write_text("<svg/>")
    return d


def test_a_stored_measurement_comes_back_with_its_files(tmp_path):
    eval_dir = _eval_dir(tmp_path)
    cache = ProductCache(tmp_path / "cache", {"tau": 0.01})
    key = cache.key("mvs", ["a" * 64, "b" * 64])
    metrics = {
        "skipped": False,
        "reason": None,
        "c2c": {"mean": 0.002, "files": {"histogram": "plots/c2c_mvs_hist.svg"}},
    }
    table = {"wood": {"c2c_mean": 0.001}}
    cache.store(key, eval_dir, ["c2c_mvs.ply", "plots/c2c_mvs_hist.svg"], metrics, table)

    fresh = tmp_path / "other_project" / "eval"
    restored = cache.restore(key, fresh)
    assert restored is not None
    assert restored.metrics == metrics and restored.per_material == table
    assert restored.files == ("c2c_mvs.ply", "plots/c2c_mvs_hist.svg")
    assert (fresh / "c2c_mvs.ply").read_bytes() == (eval_dir / "c2c_mvs.ply").read_bytes()
    assert (fresh / "plots" / "c2c_mvs_hist.svg").read_text() == "<svg/>"
    assert sorted(files_in(fresh)) == ["c2c_mvs.ply", "plots/c2c_mvs_hist.svg"]


def test_keys_follow_the_product_its_files_and_the_settings(tmp_path):
    cache = ProductCache(tmp_path, {"tau": 0.01, "reference": "r" * 64})
    base = cache.key("merged", ["a", "b"])
    assert base == ProductCache(tmp_path, {"reference": "r" * 64, "tau": 0.01}).key("merged", ["a", "b"])
    assert len({
        base,
        cache.key("merged", ["a", "c"]),  # a product file changed
        cache.key("merged", ["b", "a"]),  # files are not interchangeable
        cache.key("splats", ["a", "b"]),  # another product (its files are named after it)
        ProductCache(tmp_path, {"tau": 0.02, "reference": "r" * 64}).key("merged", ["a", "b"]),  # another τ
        ProductCache(tmp_path, {"tau": 0.01, "reference": "s" * 64}).key("merged", ["a", "b"]),  # another reference
    }) == 6  # fmt: skip


def test_the_evaluation_code_is_part_of_the_key():
    digest = code_digest()
    assert len(digest) == 64 and digest == code_digest()


def test_missing_or_interrupted_entries_are_not_restored(tmp_path):
    eval_dir = _eval_dir(tmp_path)
    cache = ProductCache(tmp_path / "cache", {})
    key = cache.key("mvs", ["a"])
    assert cache.restore(key, tmp_path / "fresh") is None
    # a store killed before its rename leaves only a hidden staging folder, which is never read
    staging = tmp_path / "cache" / f".{key}.dead"
    (staging / "files").mkdir(parents=True)
    (staging / ENTRY).write_text('{"files": [], "metrics": {}, "per_material": null}')
    assert cache.restore(key, tmp_path / "fresh") is None
    # an entry without its entry.json (a folder someone emptied) is not complete either
    (tmp_path / "cache" / key).mkdir()
    assert cache.restore(key, tmp_path / "fresh") is None
    cache.store(key, eval_dir, ["c2c_mvs.ply"], {"skipped": False}, None)
    assert cache.restore(key, tmp_path / "fresh") == StoredMeasurement(("c2c_mvs.ply",), {"skipped": False}, None)


def test_a_damaged_entry_is_measured_again_and_replaced(tmp_path):
    eval_dir = _eval_dir(tmp_path)
    cache = ProductCache(tmp_path / "cache", {})
    key = cache.key("mvs", ["a"])
    cache.store(key, eval_dir, ["c2c_mvs.ply"], {"skipped": False}, None)
    entry = tmp_path / "cache" / key
    (entry / "files" / "c2c_mvs.ply").unlink()  # a stored file deleted
    assert cache.restore(key, tmp_path / "fresh") is None
    (entry / ENTRY).write_text('{"files": [], "metr')  # truncated
    assert cache.restore(key, tmp_path / "fresh") is None
    (entry / ENTRY).write_text('{"files": []}')  # keys missing
    assert cache.restore(key, tmp_path / "fresh") is None
    cache.store(key, eval_dir, ["c2c_mvs.ply"], {"skipped": True}, None)  # the new measurement replaces it
    assert cache.restore(key, tmp_path / "fresh").metrics == {"skipped": True}
