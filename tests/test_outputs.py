"""Files volmc writes (volmc/outputs.py): checked before the work, written whole."""

import os
import stat

import numpy as np
import pytest

from volmc.film import read_exr, write_exr
from volmc.outputs import check_output, written_whole
from volmc.scene.errors import SceneError


def test_check_output_refuses_what_cannot_be_written(tmp_path):
    fifo = tmp_path / "pipe.exr"
    os.mkfifo(fifo)
    (tmp_path / "dir.exr").mkdir()
    cases = [(tmp_path / "dir.exr", "expected a file path"),
             (str(tmp_path) + os.sep, "expected a file path"),
             (fifo, "not a regular file"),
             (tmp_path / "missing" / "a.exr", "directory does not exist"),
             # root passes os.access everywhere, and /proc refuses new files to anyone
             ("/proc/volmc.exr", "directory is not writable"),
             (tmp_path / ("\u00e9" * 128 + ".exr"), "not a usable file name")]   # 261 bytes
    for path, words in cases:
        with pytest.raises(SceneError, match=words) as e:
            check_output(path, "-o")
        assert str(e.value).startswith("command line: -o: ")
    check_output(tmp_path / "fine.exr", "-o")
    assert set(os.listdir(tmp_path)) == {"pipe.exr", "dir.exr"}   # the probe is gone


def test_check_output_follows_links_as_the_writers_do(tmp_path):
    # The writers write where a link points, so a link into a missing or unwritable
    # directory is refused before the render, not found when its image is ready.
    cases = [("dangling.exr", tmp_path / "missing" / "out.exr", "directory does not exist"),
             ("proc.exr", "/proc/version", "directory is not writable")]
    for name, target, words in cases:
        (tmp_path / name).symlink_to(target)
        with pytest.raises(SceneError, match=words):
            check_output(tmp_path / name, "-o")
    (tmp_path / "sub").mkdir()
    (tmp_path / "good.exr").symlink_to(tmp_path / "sub" / "new.exr")
    check_output(tmp_path / "good.exr", "-o")


def test_written_whole_keeps_the_old_file_when_writing_fails(tmp_path):
    path = tmp_path / "grid.vol"
    path.write_bytes(b"the earlier file")
    with pytest.raises(OverflowError):
        with written_whole(path) as tmp:
            with open(tmp, "wb") as f:
                f.write(b"half of the new")
                raise OverflowError("a value the format cannot hold")
    assert path.read_bytes() == b"the earlier file"
    assert os.listdir(tmp_path) == ["grid.vol"]


def test_written_whole_gives_plain_permissions(tmp_path):
    """A new file gets 0666 less the umask (not mkstemp's 0600); a replaced file keeps its
    mode; a symbolic link is written through, not replaced by a file."""
    old_mask = os.umask(0o027)
    try:
        new = tmp_path / "new.exr"
        write_exr(new, np.ones((2, 3, 4), np.float32))
    finally:
        os.umask(old_mask)
    assert stat.S_IMODE(new.stat().st_mode) == 0o640
    link = tmp_path / "link.exr"
    link.symlink_to(new)
    write_exr(link, np.full((2, 3, 4), 7.0, np.float32))
    assert link.is_symlink() and read_exr(new, alpha=True)[0].min() == 7.0
    link.unlink()
    old = tmp_path / "old.exr"
    write_exr(old, np.zeros((2, 3, 4), np.float32))
    os.chmod(old, 0o640)
    write_exr(old, np.ones((2, 3, 4), np.float32))
    assert stat.S_IMODE(old.stat().st_mode) == 0o640
    assert read_exr(old, alpha=True)[0].min() == 1.0
    assert sorted(os.listdir(tmp_path)) == ["new.exr", "old.exr"]


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0,
                    reason="only root may give a file to another user")
def test_written_whole_keeps_the_owner(tmp_path):
    """Root rendering over a user's file leaves it the user's, with its mode."""
    path = tmp_path / "theirs.exr"
    write_exr(path, np.zeros((2, 3, 4), np.float32))
    os.chown(path, 4321, 8765)
    os.chmod(path, 0o604)
    write_exr(path, np.ones((2, 3, 4), np.float32))
    st = path.stat()
    assert (st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)) == (4321, 8765, 0o604)
    assert read_exr(path, alpha=True)[0].min() == 1.0


def test_written_whole_keeps_extended_attributes(tmp_path):
    """ACLs and other extended attributes of a replaced file stay with it."""
    path = tmp_path / "tagged.exr"
    write_exr(path, np.zeros((2, 3, 4), np.float32))
    try:
        os.setxattr(path, "user.volmc.test", b"kept")
    except (AttributeError, OSError):
        pytest.skip("no user extended attributes on this filesystem")
    write_exr(path, np.ones((2, 3, 4), np.float32))
    assert os.getxattr(path, "user.volmc.test") == b"kept"
    assert read_exr(path, alpha=True)[0].min() == 1.0


def test_a_render_that_cannot_be_written_is_rescued(tmp_path):
    """Should the EXR fail after all (its directory gone since the check), the image is
    written to the temporary directory and the one-line error names it."""
    from volmc.cli.render import _write_or_rescue
    rgba = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    with pytest.raises(SceneError, match="the image is saved as") as e:
        _write_or_rescue(str(tmp_path / "gone" / "out.exr"), rgba, {"spp": 4})
    rescued = str(e.value).rsplit(" ", 1)[1]
    try:
        img, meta = read_exr(rescued, alpha=True)
        np.testing.assert_array_equal(img, rgba)
        assert meta["spp"] == 4
    finally:
        os.unlink(rescued)
