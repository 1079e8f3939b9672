"""RVL, the lossless depth codec of compressed_depth_image_transport (A. D. Wilson, "Fast Lossless
Depth Image Compression", ISS 2017): runs of zeros and of non-zero pixels, each pixel the zigzag
delta from the previous non-zero one, every number in 3-bit groups (lowest first) of 4-bit
nibbles whose top bit says another follows, the nibbles packed from the top of little-endian
32-bit words. Imported only when a log holds RVL images (``compressed_depth``)."""

from __future__ import annotations

import numpy as np

from ..jit import njit


@njit(cache=True, nogil=True)
def _vle(words, wi, word, left):
    """The next number: (value, or -1 when the words end or it overflows; wi, word, left)."""
    value = 0
    shift = 0
    while True:
        if left == 0:
            if wi >= words.shape[0]:
                return -1, wi, word, left
            word = words[wi]
            wi += 1
            left = 8
        nib = (word >> np.uint32(28)) & np.uint32(15)
        word = word << np.uint32(4)
        left -= 1
        value |= np.int64(nib & np.uint32(7)) << shift
        shift += 3
        if not nib & np.uint32(8):
            return value, wi, word, left
        if shift > 33:  # more than any run or delta of a 16-bit image needs
            return -1, wi, word, left


@njit(cache=True, nogil=True)
def rvl_decode(words, out):
    """Decode the uint32 ``words`` into ``out`` (uint16, the image's size): 0 done, 1 the
    stream ended first (or held a number too long), 2 a run went past the image's end."""
    n = out.shape[0]
    i = 0
    wi, word, left = 0, np.uint32(0), 0
    prev = 0
    while i < n:
        for zero_run in (True, False):  # a run of zeros, then one of non-zero pixels
            run, wi, word, left = _vle(words, wi, word, left)
            if run < 0:
                return 1
            if run > n - i:
                return 2
            for _ in range(run):
                if not zero_run:
                    pos, wi, word, left = _vle(words, wi, word, left)
                    if pos < 0:
                        return 1
                    prev = (prev + ((pos >> 1) ^ -(pos & 1))) & 0xFFFF  # the zigzag delta
                out[i] = 0 if zero_run else prev
                i += 1
    return 0
