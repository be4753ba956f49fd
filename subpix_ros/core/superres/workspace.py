"""Working arrays a reconstruction reuses from one frame set to the next.

A set's largest arrays (the frame spectra, the luminance stack, the packed HR spectrum) are
frame-set sized; allocated fresh for every set, they are pages the kernel maps in and zeroes
on first touch (and, where numpy asks for transparent huge pages, compacts memory for). A
:class:`Workspace` held by the caller (the reconstruction stage) hands the same memory back
for every set. Sizes and measurements: docs/design-notes.md ("The reconstruction's buffers
reused from set to set").
"""

from __future__ import annotations

import numpy as np

__all__ = ["Workspace", "work_array"]


class Workspace:
    """Named scratch arrays, kept between calls and handed out again for the next.

    Each name owns one buffer. :meth:`array` returns a C-contiguous view of the requested
    shape and type on the front of that buffer, growing it (a new allocation) only when
    the request is larger than any before. The contents are left over from the last use,
    as with ``numpy.empty``: callers write every element they read.

    Not thread-safe: one workspace per reconstruction thread. A view handed out stays
    valid until the next :meth:`array` call with the same name, or :meth:`clear`; never
    return one to a caller that may keep it.
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        """Return the uninitialised array ``name`` of ``shape`` and ``dtype``.

        Parameters
        ----------
        name : str
            The buffer's name (one buffer per name).
        shape : tuple of int
            The array's shape.
        dtype : numpy dtype
            The array's type.

        Returns
        -------
        numpy.ndarray
            A C-contiguous view on the named buffer (its previous contents).
        """
        dt = np.dtype(dtype)
        shape = tuple(int(s) for s in shape)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        buf = self._buffers.get(name)
        if buf is None or buf.nbytes < nbytes:
            buf = np.empty(max(nbytes, 1), np.uint8)
            self._buffers[name] = buf
        return buf[:nbytes].view(dt).reshape(shape)

    @property
    def nbytes(self) -> int:
        """Bytes held by all buffers."""
        return sum(b.nbytes for b in self._buffers.values())

    def clear(self) -> None:
        """Drop every buffer (their memory goes back to the allocator)."""
        self._buffers.clear()


def work_array(workspace: Workspace | None, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """Return ``workspace.array(name, shape, dtype)``, or a new ``numpy.empty`` without one."""
    if workspace is None:
        return np.empty(shape, dtype)
    return workspace.array(name, shape, dtype)
