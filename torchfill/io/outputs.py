"""The one guarded writer of a run: every file the command line writes goes through it.

An :class:`Outputs` knows what a run reads (inputs, training recordings) and what it will write
(the filled recording, ``--std``, ``--report``, ``qc -o``, batch outputs, experiment results), and
checks all of it *before* any work starts:

- an output may not land on a file the run reads, nor on another output of the same run. Paths are
  compared where they land (the folder resolved, so ``./a.c3d``, ``a.c3d`` and ``link/a.c3d`` are
  one file) and by device and inode (so a hard link of an input is caught too); ``replace_input``
  lets ``--in-place`` write onto its own input, nothing else;
- the folder of every output must exist, be a folder and be writable; an output may not be an
  existing folder (a recording is a file) or an existing read-only file.

Writing (:meth:`Outputs.write`) is atomic, and a run is all or nothing: the format writer
serialises into a private folder next to the target (same file system, same file name, so messages
read the same) and the data is synced to disk; the files are renamed over their targets together
at :meth:`Outputs.commit` (the end of the ``with`` block), once every output of the run is ready.
A failure at any point (a full disk, an error, a signal) leaves every old file as it was and no
new or temporary file behind: an error exit means nothing new on disk. A symbolic link at the
target is replaced by the new file; its target is never written.

Write-back (a C3D or TRC written into a copy of its source file) takes its template from a private
copy of the source made just before it was read (:meth:`Outputs.add_input` with
``template=True``, then :meth:`Outputs.keep_templates`), not from whatever is on disk at write time: a source replaced during a long fill
cannot leak into the output, and the warning then says what happened.
"""
from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from . import FileFormatError

#: > 0 while a file is being renamed into place; a worker's SIGTERM handler waits for it to finish
WRITING = 0
_TMP_TAG = ".torchfill-"


@dataclass(frozen=True)
class _Read:
    role: str            # "input" or "training"
    path: Path
    real: str            # the fully resolved path (what a reader opens)
    landing: str         # the folder resolved, the name kept
    ident: tuple | None  # (st_dev, st_ino) of what a reader opens


@dataclass(frozen=True)
class _Write:
    what: str
    path: Path
    landing: str
    replaces_input: bool


@dataclass
class _Staged:
    path: Path
    landing: str
    holder: Path | None  # private folder beside the target holding the new file
    tmp: Path | None     # the new file (None: ``action`` writes it at commit)
    action: Callable[[], None] | None = None
    undo: Callable[[], None] | None = None      # what staging made besides (a backup)


@dataclass
class _Template:
    copy: Path | None    # private copy of a source file (None: folders, formats not written back)
    stamp: tuple         # the source's fingerprint when it was copied
    folder: bool = False


#: suffixes whose writers build the output from the source file's bytes
WRITE_BACK = (".c3d", ".trc")


class Outputs:
    """The files one run reads and writes; see the module notes. Use as a context manager (the
    private copies of write-back templates are removed at exit)."""

    def __init__(self):
        self._reads: list[_Read] = []
        self._writes: list[_Write] = []
        self._templates: dict[str, _Template] = {}
        self._wanted: list[_Read] = []
        self._private: Path | None = None
        self._staged: list[_Staged] = []

    # -- what the run reads --------------------------------------------------------------------
    def add_input(self, path, role: str = "input", *, template: bool = False) -> Path:
        """Register a file (or OpenPose folder) the run reads (its content is not read here).
        ``template``: :meth:`keep_templates` keeps a private copy of it for a write-back later
        (see the module notes)."""
        path = Path(path)
        try:
            real = os.path.realpath(path)
            ident = _ident(os.stat(path))
        except (OSError, ValueError):
            real, ident = os.path.abspath(path), None
        read = _Read(role, path, real, _landing_or_abs(path), ident)
        self._reads.append(read)
        if template:
            self._wanted.append(read)
        return path

    def keep_templates(self) -> None:
        """Copy the template inputs privately; call just before reading them (and
        :meth:`confirm_inputs` just after)."""
        for read in self._wanted:
            if read.real not in self._templates and os.path.exists(read.path):
                self._templates[read.real] = self._keep(read.path)
        self._wanted = []

    def confirm_inputs(self) -> None:
        """Raise if a template source changed between its copy and now (call after reading it:
        then the data read and the template are the same bytes)."""
        for read in self._reads:
            kept = self._templates.get(read.real)
            if kept is not None and _stamp(read.path) != kept.stamp:
                raise FileFormatError(f"{read.path}: changed while it was being read; run again "
                                      "once the file is complete")

    def _keep(self, path: Path) -> _Template:
        before = _stamp(path)
        if path.is_dir():                                    # a folder: remember its state only
            return _Template(None, before, True)
        if path.suffix.lower() not in WRITE_BACK:            # no template needed, only the stamp
            return _Template(None, before, False)
        if self._private is None:
            self._private = Path(tempfile.mkdtemp(prefix="torchfill-template-"))
        holder = Path(tempfile.mkdtemp(dir=self._private))
        copy = holder / path.name                            # same name: messages read the same
        try:
            shutil.copyfile(path, copy)
        except OSError as err:
            raise FileFormatError(f"{path}: cannot read ({err.strerror or err})") from None
        if _stamp(path) != before:
            raise FileFormatError(f"{path}: changed while it was being read; run again once the "
                                  "file is complete")
        return _Template(copy, before)

    def template(self, seq):
        """``seq`` with its ``source`` pointing at the private copy taken at the start (a
        write-back then uses the bytes the run read); a warning if the file on disk changed since.
        A changed source folder (OpenPose) is refused: its frames cannot be kept privately."""
        source = getattr(seq, "source", None)
        if source is None:
            return seq
        kept = self._templates.get(os.path.realpath(source))
        if kept is None:
            return seq
        changed = _stamp(Path(source)) != kept.stamp
        if kept.copy is None:
            if changed and kept.folder:
                raise FileFormatError(f"{source}: changed during the fill; nothing written (run "
                                      "again on the complete folder)")
            return seq
        if changed:
            warnings.warn(f"{source} changed on disk during the fill; the output is built from the "
                          "content read at the start, the file's current content is not used")
        return replace(seq, source=kept.copy)

    # -- what the run writes -------------------------------------------------------------------
    def add_output(self, path, what: str = "output", *, replace_input: bool = False,
                   folder: bool = False, hint: str = "") -> Path:
        """Register a path the run will write; raises :class:`FileFormatError` (one line) now if
        it could not or must not be written. ``folder``: the output is a folder (OpenPose)."""
        path = Path(path)
        landing = self._check(path, what, replace_input=replace_input, folder=folder, hint=hint)
        self._writes.append(_Write(what, path, landing, replace_input))
        return path

    def _check(self, path: Path, what: str, *, replace_input: bool, folder: bool, hint: str,
               me: _Write | None = None) -> str:
        if path.name in ("", ".", ".."):
            raise FileFormatError(f"{path}: {what} is a folder; give a file name")
        parent = check_folder(path.parent if str(path.parent) else Path("."), path)
        landing = os.path.join(os.path.realpath(parent), path.name)
        try:
            st = os.lstat(landing)
        except FileNotFoundError:
            st = None
        except OSError as err:
            raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
        if st is not None and stat.S_ISDIR(st.st_mode) and not folder:
            raise FileFormatError(f"{path}: {what} is an existing folder; give a file name")
        if st is not None and stat.S_ISREG(st.st_mode) and not (
                st.st_mode & 0o222 and os.access(landing, os.W_OK)):
            raise FileFormatError(f"{path}: cannot write, the file is read-only")
        ident = _ident(st) if st is not None and not stat.S_ISLNK(st.st_mode) else None
        for read in self._reads:
            same = landing in (read.real, read.landing) or (
                ident is not None and ident == read.ident)
            if not same:
                continue
            if replace_input and read.role == "input" and landing in (read.real, read.landing):
                continue
            raise FileFormatError(f"{path}: the {what} would overwrite the {read.role} "
                                  f"{read.path}{'; ' + hint if hint else ''}")
        for other in self._writes:
            if other is me:
                continue
            if landing == other.landing or (ident is not None and ident == _lident(other.landing)):
                raise FileFormatError(f"{path}: the {what} would overwrite the {other.what} "
                                      f"{other.path} of this run; give them different names")
        return landing

    def write(self, path, serialise: Callable[[Path], None], what: str = "output",
              undo: Callable[[], None] | None = None) -> Path:
        """Stage ``path``: ``serialise(tmp)`` writes the content to ``tmp`` (a path in a private
        folder beside ``path``, with ``path``'s name), synced now and renamed over ``path`` at
        :meth:`commit`. ``path`` is registered now if it was not; the checks run again at write
        time. ``undo`` removes what ``serialise`` made besides (run if the run fails)."""
        path = Path(path)
        me = next((w for w in self._writes if w.path == path), None)
        if me is None:
            self.add_output(path, what)
            me = self._writes[-1]
        landing = self._check(path, me.what, replace_input=me.replaces_input, folder=False,
                              hint="", me=me)
        folder = Path(os.path.dirname(landing))
        try:
            holder = Path(tempfile.mkdtemp(prefix=f".{path.name}{_TMP_TAG}", dir=folder))
        except OSError as err:
            self.discard()
            raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
        tmp = holder / path.name
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                serialise(tmp)
            for w in caught:                  # the writer named the private path: name the target
                warnings.warn_explicit(_renamed(w.message, tmp, path), w.category, w.filename,
                                       w.lineno)
            _settle(tmp, landing)
            companions = self._companions(holder, tmp, path, me.what)
        except BaseException as err:
            shutil.rmtree(holder, ignore_errors=True)
            if undo is not None:
                undo()
            self.discard()
            if isinstance(err, FileFormatError):
                raise FileFormatError(_renamed(err, tmp, path)) from None
            if isinstance(err, OSError):
                kept = ", the existing file is unchanged" if os.path.lexists(landing) else ""
                raise FileFormatError(f"{path}: cannot write ({err.strerror or err}); nothing "
                                      f"written{kept}") from None
            raise
        self._staged += companions
        self._staged.append(_Staged(path, landing, holder, tmp, undo=undo))
        return path

    def _companions(self, holder: Path, tmp: Path, path: Path, what: str) -> list["_Staged"]:
        """Files a format writer left beside ``tmp`` (a TRC's ``.filled`` record): checked and
        registered like an output, synced, staged to land beside ``path``."""
        staged = []
        for extra in sorted(holder.iterdir()):
            if extra.name == tmp.name:
                continue
            target = path.with_name(extra.name)
            if not any(w.path == target for w in self._writes):
                self.add_output(target, f"record of the {what}")
            landing = self._check(target, f"record of the {what}", replace_input=False,
                                  folder=False, hint="",
                                  me=next(w for w in self._writes if w.path == target))
            _settle(extra, landing)
            staged.append(_Staged(target, landing, None, extra))
        return staged

    def commit(self) -> None:
        """Put every staged output in place (folders written by their own writer first, then
        the files renamed over their targets); on a failure, the targets renamed so far get
        their old files back and nothing new is left. Called at the end of the ``with`` block."""
        staged, self._staged = self._staged, []
        done: list[tuple[_Staged, Path | None]] = []
        item = staged[0] if staged else None
        global WRITING
        WRITING += 1
        try:
            for item in [s for s in staged if s.action is not None]:
                item.action()
            for item in [s for s in staged if s.action is None]:
                old = _keep_old(item)
                os.replace(item.tmp, item.landing)
                done.append((item, old))
            for folder in {os.path.dirname(s.landing) for s in staged}:
                _sync_folder(Path(folder))
        except BaseException as err:
            for put, old in reversed(done):
                if old is not None:
                    os.replace(old, put.landing)
                else:
                    Path(put.landing).unlink(missing_ok=True)
            self._staged = staged
            self.discard()
            if isinstance(err, OSError):
                raise FileFormatError(f"{item.path}: cannot write ({err.strerror or err}); "
                                      "nothing written") from None
            raise
        finally:
            WRITING -= 1
        for item in staged:
            if item.holder is not None:
                shutil.rmtree(item.holder, ignore_errors=True)

    def discard(self) -> None:
        """Drop every staged output (nothing of this run is written)."""
        staged, self._staged = self._staged, []
        for item in staged:
            if item.holder is not None:
                shutil.rmtree(item.holder, ignore_errors=True)
            if item.undo is not None:
                item.undo()

    def write_text(self, path, text: str, what: str = "output") -> Path:
        return self.write(path, lambda tmp: tmp.write_bytes(text.encode("utf-8")), what)

    def write_sequence(self, seq, path, what: str = "output", backup: Path | None = None,
                       **kwargs) -> Path:
        """Stage a recording with the format writer of ``path``'s suffix (through the write-back
        template, see :meth:`template`; ``kwargs`` go to the writer). ``backup``: first keep the
        file at ``path`` under this name (a hard link where possible, else a copy); removed again
        if the run fails."""
        from . import _pick

        path = Path(path)
        source = getattr(seq, "source", None)
        if source is not None and os.path.realpath(source) not in self._templates:
            _refuse_changed_source(seq, path)
        seq = self.template(seq)
        if path.is_dir() or not path.suffix:      # an OpenPose folder: its own atomic write
            me = next((w for w in self._writes if w.path == path), None)
            landing = self._check(path, what, replace_input=False, folder=True, hint="", me=me)
            self._staged.append(_Staged(path, landing, None, None,
                                        action=lambda: _pick(path, "write")(seq, path, **kwargs)))
            return path
        made = False

        def serialise(tmp: Path) -> None:
            nonlocal made
            _pick(tmp, "write")(seq, tmp, **kwargs)
            if backup is not None:
                _copy_aside(path, backup)
                made = True

        def undo() -> None:
            if made:
                Path(backup).unlink(missing_ok=True)
        return self.write(path, serialise, what, undo=undo)

    def close(self) -> None:
        """Drop what was not committed, and the private copies of the templates."""
        self.discard()
        if self._private is not None:
            shutil.rmtree(self._private, ignore_errors=True)
            self._private = None

    def __enter__(self) -> "Outputs":
        return self

    def __exit__(self, kind, *exc) -> None:
        try:
            if kind is None:
                self.commit()
        finally:
            self.close()

    def __del__(self):
        self.close()


def check_folder(folder: Path, path: Path | None = None) -> Path:
    """``folder`` if files can be created in it, else a one-line :class:`FileFormatError` naming
    ``path`` (or the folder): missing, not a folder, a symbolic link loop, not writable."""
    name = path if path is not None else folder
    try:
        st = os.stat(folder)
    except OSError as err:
        problem = {errno.ENOENT: f"folder {folder} does not exist",
                   errno.ELOOP: f"folder {folder} is a symbolic link loop",
                   errno.ENOTDIR: f"{folder} is not a folder"}.get(
            err.errno, f"cannot use folder {folder} ({err.strerror or err})")
        raise FileFormatError(f"{name}: cannot write, {problem}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise FileFormatError(f"{name}: cannot write, {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise FileFormatError(f"{name}: cannot write into folder {folder} (permission denied)")
    return folder


def make_folder(folder) -> Path:
    """Create ``folder`` (and its parents) if needed; one-line :class:`FileFormatError` on a
    symbolic link loop, a file in the way or no permission."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (OSError, RuntimeError) as err:
        check_folder(folder)                  # names the problem where it can
        raise FileFormatError(f"{folder}: cannot create the folder "
                              f"({getattr(err, 'strerror', None) or err})") from None
    return check_folder(folder)


def sweep(path) -> None:
    """Remove what an interrupted write of ``path`` (a killed process) left beside it."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    try:
        for entry in folder.iterdir():
            if entry.name.startswith(f".{path.name}{_TMP_TAG}") and entry.is_dir() \
                    and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
    except OSError:
        pass


def _copy_aside(path: Path, backup: Path) -> None:
    if os.path.lexists(backup):
        raise FileFormatError(f"{backup}: exists; move it away first (it may hold an earlier "
                              "original)")
    try:
        os.link(path, backup)
    except OSError:
        shutil.copy2(path, backup)


def estimate_path(output) -> Path:
    """Where a fill's error estimate goes beside its output ``OUT.EXT``: ``OUT.EXT.std.csv``
    (``torchfill qc`` looks for it there)."""
    output = Path(output)
    return output.with_name(output.name + ".std.csv")


def source_stamp(path) -> tuple:
    """The fingerprint :func:`torchfill.read` keeps of the file it read (``meta["source_stamp"]``)."""
    return _stamp(Path(path))


def _refuse_changed_source(seq, path: Path) -> None:
    """A write-back into a copy of ``seq``'s source file (same format) when that file is no
    longer the one read (no private template of it kept by this run): one line, nothing
    written. Its other bytes would come from the new file, the samples from the old one."""
    source, stamp = getattr(seq, "source", None), getattr(seq, "meta", {}).get("source_stamp")
    if source is None or stamp is None:
        return
    suffix = Path(source).suffix.lower()
    if suffix not in WRITE_BACK or path.suffix.lower() != suffix:
        return
    if _stamp(Path(source)) != tuple(stamp):
        raise FileFormatError(f"{source}: changed on disk since it was read; nothing written to "
                              f"{path} (read it again, or write another format)")


def _keep_old(item: _Staged) -> Path | None:
    """A hard link to the file a staged output replaces, in its private folder (None: no file
    there, or it cannot be linked: then a failed run cannot give it back)."""
    if item.holder is None or not os.path.isfile(item.landing) or os.path.islink(item.landing):
        return None
    old = item.holder / (item.path.name + ".old")
    try:
        os.link(item.landing, old)
    except OSError:
        return None
    return old


def _ident(st: os.stat_result) -> tuple:
    return (st.st_dev, st.st_ino)


def _lident(path: str) -> tuple | None:
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return None if stat.S_ISLNK(st.st_mode) else _ident(st)


def _landing_or_abs(path: Path) -> str:
    parent = path.parent if str(path.parent) else Path(".")
    try:
        return os.path.join(os.path.realpath(parent), path.name)
    except (OSError, ValueError):
        return os.path.abspath(path)


def _stamp(path: Path) -> tuple:
    """A file's fingerprint (device, inode, size, modification time); a folder's: its entries'."""
    try:
        st = os.stat(path)
        if stat.S_ISDIR(st.st_mode):
            return tuple(sorted((e.name, e.stat().st_size, e.stat().st_mtime_ns)
                                for e in os.scandir(path) if e.is_file()))
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        return ()


def _settle(staged: Path, landing) -> None:
    """A staged file synced to disk and given the mode of the file it will replace."""
    fd = os.open(staged, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.chmod(staged, _mode_for(landing))


def _mode_for(landing: str) -> int:
    """Permission bits of the new file: the replaced regular file's, else 0o666 minus the umask."""
    try:
        st = os.lstat(landing)
        if stat.S_ISREG(st.st_mode):
            return st.st_mode & 0o777
    except OSError:
        pass
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def _sync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _renamed(message, tmp: Path, path: Path) -> str:
    return str(message).replace(str(tmp), str(path))


__all__ = ["Outputs", "check_folder", "estimate_path", "make_folder", "sweep"]
