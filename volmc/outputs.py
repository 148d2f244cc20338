"""Files volmc writes: checked before the work that fills them, and written whole.

A render or a benchmark can run for hours, so every path it will write is checked before it
starts (``check_output``): a file path (not a directory, not a FIFO or device), in a
directory where a file can really be created. The check creates and removes a probe file
rather than trusting ``os.access``, which reads permission bits: root passes those
everywhere, and some filesystems (/proc, read-only mounts) refuse what the bits allow.

Every file is then written to a temporary file in its directory and renamed over the path
(``written_whole``), so a failure or a kill while writing leaves the earlier file as it was,
never a truncated one; the new file gets the permissions a plain ``open`` would give it
(those of the file it replaces, else 0666 less the umask), not mkstemp's 0600.
"""

import contextlib
import errno
import os
import shutil
import stat
import tempfile

from .scene.errors import SceneError


def umask():
    """The process's umask: from /proc on Linux (os.umask can only read it by setting it,
    which races with other threads), else by setting and restoring it."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_output(path, key, where="command line"):
    """Raise SceneError(where, key, ...) unless ``path`` can be written as a file."""
    try:
        path = os.fsdecode(path)
    except TypeError:
        raise SceneError(where, key, f"expected a file path, got {type(path).__name__}") \
            from None
    if "\0" in path or len(os.fsencode(os.path.basename(path))) > 255:   # NAME_MAX bytes
        raise SceneError(where, key, f"not a usable file name: {path[:80]!r}")
    if not path or path.endswith(("/", os.sep)) or os.path.isdir(path):
        raise SceneError(where, key, f"expected a file path, got {path!r}")
    if os.path.exists(path) and not os.path.isfile(path):
        raise SceneError(where, key, f"not a regular file: {path}")
    # The writers (write_atomically) write where a link points: probe that directory.
    d = os.path.dirname(os.path.realpath(path))
    if not os.path.isdir(d):
        raise SceneError(where, key, f"directory does not exist: {d}")
    check_directory_writable(d, key, where)


def check_directory_writable(d, key, where="command line"):
    """Raise SceneError(where, key, ...) unless a file can be created in directory ``d``."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".volmc-probe-", dir=d)
    except OSError:
        raise SceneError(where, key, f"directory is not writable: {d}") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def write_json(path, payload, indent=2, default=None, key="--json"):
    """``payload`` as JSON at ``path``, written whole (reports of benchmarks and peers). The
    path was checked before the work; should writing fail all the same (its folder removed
    meanwhile), the report goes to the temporary directory and the one-line error names
    ``key`` and the copy."""
    import json
    text = json.dumps(payload, indent=indent, default=default)
    try:
        with written_whole(path) as tmp, open(tmp, "w") as f:
            f.write(text)
    except OSError as e:
        fd, copy = tempfile.mkstemp(prefix="volmc-report-", suffix=".json")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        raise SceneError("command line", key, f"cannot write {path} ({e.strerror or e}); "
                                              f"the report is in {copy}") from None


def _copy_xattrs(src, dst):
    """The extended attributes of src (POSIX ACLs are system.posix_acl_access) onto dst,
    each one the filesystem and the user allow."""
    if not hasattr(os, "listxattr"):
        return
    try:
        names = os.listxattr(src)
    except OSError:
        return
    for name in names:
        with contextlib.suppress(OSError):
            os.setxattr(dst, name, os.getxattr(src, name))


@contextlib.contextmanager
def written_whole(path, suffix=""):
    """Yields a temporary path beside ``path`` to write; renames it over ``path`` when the
    block ends without an exception, and removes it otherwise. ``suffix``: the temporary
    file's (writers that choose the format by suffix need the path's own). A symbolic link
    is written through (the file it names is replaced, in that file's directory); where the
    rename cannot replace the file (a file bind-mounted into a container: EBUSY), the
    temporary file is copied into it instead. The new file keeps the mode, the extended
    attributes (ACLs among them) of the one it replaces, and its owner and group where the
    user may set them."""
    path = os.path.realpath(os.fspath(path))
    d = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(prefix=".volmc-", suffix=suffix, dir=d)
    os.close(fd)
    try:
        yield tmp
        try:
            st = os.stat(path)
        except OSError:
            st = None
        if st is not None and (st.st_uid, st.st_gid) != (os.getuid(), os.getgid()):
            # The replaced file's owner and group go on (root rendering into a user's
            # file); a user who may not give files away keeps the new one, as an editor does.
            with contextlib.suppress(OSError):
                os.chown(tmp, st.st_uid, st.st_gid)
        os.chmod(tmp, stat.S_IMODE(st.st_mode) if st is not None else 0o666 & ~umask())
        if st is not None:
            _copy_xattrs(path, tmp)
        try:
            os.replace(tmp, path)
        except OSError as e:
            if e.errno not in (errno.EBUSY, errno.EXDEV):
                raise
            shutil.copyfile(tmp, path)
            os.unlink(tmp)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
