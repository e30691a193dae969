"""Seals, completion records and output folders: what says an output is intact and finished.

Digests are checked against hashlib on the bytes the docstrings name; the reasons against
the cases each describes.
"""

import hashlib
import json

from vitaplace.engine.outputs import checksum, completion
from vitaplace.engine.outputs.outdir import COMPLETED, LOCK_NAME, remove_stale_temporaries


def test_digest_of_a_folder_is_that_of_its_names_and_contents_in_order(tmp_path):
    folder = tmp_path / "model"
    (folder / "sub").mkdir(parents=True)
    (folder / "b.txt").write_bytes(b"two")
    (folder / "sub" / "a.txt").write_bytes(b"one")
    expected = hashlib.sha256(b"b.txt\0" + b"two" + b"sub/a.txt\0" + b"one").hexdigest()  # sorted by path
    assert checksum.digest(folder) == expected
    assert checksum.digest(folder / "b.txt") == hashlib.sha256(b"two").hexdigest()
    (folder / "b.txt").rename(folder / "c.txt")  # same bytes under another name: another digest
    assert checksum.digest(folder) != expected


def test_check_says_why_an_output_cannot_be_used(tmp_path):
    out = tmp_path / "features.npz"
    assert checksum.check(out, "k") == "absent"
    out.write_bytes(b"features")
    assert checksum.check(out, "k").startswith("not sealed")
    checksum.seal(out, "k")
    assert checksum.check(out, "k") is None
    assert checksum.check(out, "other") == "made for other settings"
    out.write_bytes(b"featureZ")  # a flipped byte
    assert checksum.check(out, "k").startswith("damaged")
    out.unlink()
    assert checksum.check(out, "k") == "missing"


def test_a_completion_record_notices_a_changed_file_and_scenario(tmp_path):
    (tmp_path / completion.SCENARIO).write_text("name: x\n")
    (tmp_path / "results.json").write_text("[]")
    completion.write(tmp_path, [tmp_path / "results.json"])
    record = json.loads((tmp_path / COMPLETED).read_text())
    assert record["files"] == {"results.json": hashlib.sha256(b"[]").hexdigest()}
    assert completion.problem(tmp_path, ["results.json"]) is None
    assert "not among the files" in completion.problem(tmp_path, ["manifest.json"])
    (tmp_path / "results.json").write_text("[{}]")
    assert "changed or damaged" in completion.problem(tmp_path, ["results.json"])
    (tmp_path / completion.SCENARIO).write_text("name: y\n")
    assert "a later run changed it" in completion.problem(tmp_path, [])
    completion.clear(tmp_path)
    assert "did not finish" in completion.problem(tmp_path, [])


def test_stale_temporaries_are_removed_and_the_lock_is_kept(tmp_path):
    (tmp_path / "models" / ".mupnet.123").mkdir(parents=True)  # an interrupted model folder
    part = tmp_path / "features" / ".a.npz.456.part"
    part.parent.mkdir()
    part.write_bytes(b"half")
    (tmp_path / LOCK_NAME).write_text("")
    (tmp_path / "features" / "a.npz").write_bytes(b"whole")
    removed = remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([part, tmp_path / "models" / ".mupnet.123"])
    assert (tmp_path / LOCK_NAME).exists() and (tmp_path / "features" / "a.npz").exists() and not part.exists()


def test_claiming_a_folder_locks_it_logs_the_command_in_then_cleans(tmp_path, caplog):
    import logging

    import pytest

    from vitaplace.engine.outputs.outdir import OutputDirError, OutputLock, claimed

    out = tmp_path / "out"
    (out / "cache").mkdir(parents=True)
    (out / ".vitaplace.lock").write_text("")  # a folder a vitaplace command wrote, then was killed in
    stale = out / "cache" / ".results.json.1234.part"
    stale.write_text("half")
    seen = []
    with caplog.at_level(logging.INFO, logger="vitaplace"):
        with claimed(out, lambda folder: seen.append((folder, stale.exists()))) as folder:
            assert folder == out and seen == [(out, True)]  # the callback runs before the cleaning
            assert not stale.exists()
            with pytest.raises(OutputDirError, match="another vitaplace run"), OutputLock(out):
                pass  # held while inside
    assert f"removed {stale}, left by an interrupted run" in caplog.text
    with OutputLock(out):  # released on leaving
        pass
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputDirError, match="exists and is not a directory"), claimed(tmp_path / "file"):
        pass
