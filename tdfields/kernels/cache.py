"""Compile, cache and load the kernels :mod:`tdfields.kernels.numba.source` and :mod:`tdfields.kernels.triton.source`
write.

Each specialised kernel's source goes to a file named after the hash of its text in the cache folder
(``$TDFIELDS_CACHE_DIR``, else ``$XDG_CACHE_HOME/tdfields``, else ``~/.cache/tdfields``; when none is writable,
``tdfields-kernels-v<N>-<uid>`` in the system's temporary folder, made mode 0700 and used only while it is this
user's alone, else a fresh private folder for the process) and is imported from there, so numba's own on-disk cache (``cache=True``) keeps the compiled
machine code beside it: a program is compiled once per machine, not once per process. Loaded modules are also
kept in this process, keyed by everything their text depends on.
"""

from __future__ import annotations

import atexit
import hashlib
import importlib.util
import logging
import os
import shutil
import stat
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

from tdfields.kernels.numba import source as numba_source
from tdfields.kernels.triton import source as triton_source
from tdfields.program import Program

_loaded: dict[tuple, ModuleType] = {}
_lock = threading.Lock()
#: the predictable temporary folder -> the fresh one this process uses instead (that folder was not its user's alone)
_replaced: dict[Path, Path] = {}

log = logging.getLogger("tdfields")


def cache_dir() -> Path:
    """The folder generated kernels are written to (created on first use)."""
    version = numba_source.KERNEL_VERSION
    env = os.environ.get("TDFIELDS_CACHE_DIR")
    base = Path(env) if env else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "tdfields"
    folder = base / f"kernels-v{version}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError:
        folder = _private_temporary_folder(f"tdfields-kernels-v{version}-{os.getuid()}")
    return folder


def _private_temporary_folder(name: str) -> Path:
    """``name`` in the system's temporary folder when it is this user's alone (made so if absent), else a fresh
    private folder (removed at exit; kernels are then compiled again by each process).

    Its path is predictable and the temporary folder shared: another local user could make it first. Kernels are
    imported from it and numba's cache index beside them is unpickled, so a folder someone else owns or can write
    would run their code as this user."""
    folder = Path(tempfile.gettempdir()) / name
    if folder in _replaced:
        return _replaced[folder]
    try:
        folder.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        return _replace(folder, f"cannot be made ({exc.strerror})")
    problem = _not_private(folder)
    return folder if problem is None else _replace(folder, problem)


def _not_private(folder: Path) -> str | None:
    """Why ``folder`` is not this user's alone (None when it is): a link, not a folder, another owner, or
    writable by group or others. lstat, not stat: a link planted in its place is not followed."""
    try:
        st = os.lstat(folder)
    except OSError as exc:
        return f"cannot be examined ({exc.strerror})"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    if st.st_uid != os.getuid():
        return f"is owned by uid {st.st_uid}, not by this user (uid {os.getuid()})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"has mode {stat.S_IMODE(st.st_mode):o}: group or other users can write to it"
    return None


def _replace(folder: Path, problem: str) -> Path:
    fresh = Path(tempfile.mkdtemp(prefix=f"{folder.name}-"))  # mode 0700, a name no one can guess
    atexit.register(shutil.rmtree, fresh, ignore_errors=True)
    _replaced[folder] = fresh
    log.warning("kernel cache: %s %s; using %s for this process instead (kernels compile again in each process: "
                "set TDFIELDS_CACHE_DIR to a folder of your own to keep them)", folder, problem, fresh)
    return fresh


def bounds_checked() -> bool:
    """``TDFIELDS_KERNEL_BOUNDSCHECK=1``: compile kernels with numba's index checks (slow; for tests)."""
    return os.environ.get("TDFIELDS_KERNEL_BOUNDSCHECK", "") not in ("", "0")


def forward_kernel(program: Program, widths: tuple[int, ...], dtype: str):
    """The numba ``forward`` specialised to this program, factor widths and dtype (``"float32"`` / ``"float64"``)."""
    checked = bounds_checked()
    key = ("forward", program, widths, dtype, checked)
    return _module(key, lambda: numba_source.forward_source(program, widths, dtype, checked)).forward


def backward_kernel(program: Program, widths: tuple[int, ...], want_factors: tuple[bool, ...], want_coords: bool,
                    dtype: str):
    """The numba ``backward`` producing exactly the wanted gradients."""
    checked = bounds_checked()
    key = ("backward", program, widths, want_factors, want_coords, dtype, checked)
    return _module(key, lambda: numba_source.backward_source(program, widths, want_factors, want_coords, dtype,
                                                             checked)).backward


def compose_kernels(rank: int, channels: int, dtype: str) -> ModuleType:
    """The numba ``compose_forward`` / ``compose_backward`` for rank-k planes of C channels (Six-axis)."""
    checked = bounds_checked()
    return _module(("compose", rank, channels, dtype, checked),
                   lambda: numba_source.compose_source(rank, channels, dtype, checked))


def triton_kernel(kind: str, program: Program, widths: tuple[int, ...], want_factors: tuple[bool, ...] = (),
                  want_coords: bool = False):
    """The Triton ``forward`` or ``backward`` (``kind``) for this program and widths. Triton reads
    ``TRITON_INTERPRET`` when the module is executed, so the key includes it: a test that switches the interpreter
    on gets its own copy."""
    interpret = os.environ.get("TRITON_INTERPRET", "") not in ("", "0")
    key = ("triton", triton_source.TRITON_KERNEL_VERSION, kind, program, widths, want_factors, want_coords, interpret)
    if kind == "forward":
        return _module(key, lambda: triton_source.forward_source(program, widths), interpret).forward
    return _module(key, lambda: triton_source.backward_source(program, widths, want_factors, want_coords),
                   interpret).backward


def _module(key: tuple, make_source, salt: object = None) -> ModuleType:
    """The module for ``key``: loaded in this process already, else its source (``make_source()``) written to the
    cache folder under the hash of its text (and ``salt``) and imported from there."""
    module = _loaded.get(key)
    if module is not None:
        return module
    with _lock:
        module = _loaded.get(key)
        if module is None:
            text = make_source()
            digest = hashlib.sha1((text + ("" if salt is None else repr(salt))).encode()).hexdigest()[:20]
            name = f"tdfields_kernel_{digest}"
            path = cache_dir() / f"{name}.py"
            if not path.exists() or path.read_text() != text:
                # write-then-rename: another process importing the same kernel never sees half a file
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_text(text)
                os.replace(tmp, path)
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
            _loaded[key] = module
    return module
