"""A bag of visual words learned from the sequence itself (no pretrained vocabulary: nothing is downloaded): k-means
(OpenCV) over the first keyframes' ORB descriptors, unpacked to 256 bits, with tf-idf weights. A keyframe's word
histogram, compared by cosine, ranks the places it may be."""

from __future__ import annotations

import numpy as np


def unpack(descriptors: np.ndarray) -> np.ndarray:
    """``[N, 32]`` uint8 ORB descriptors -> ``[N, 256]`` float32 bits."""
    return np.unpackbits(np.asarray(descriptors, np.uint8), axis=1).astype(np.float32)


class Vocabulary:
    """``words [K, 256]`` float32 centroids in bit space and ``idf [K]`` weights."""

    def __init__(self, words: np.ndarray, idf: np.ndarray):
        self.words = np.asarray(words, np.float32)
        self.idf = np.asarray(idf, np.float32)
        self._norm2 = (self.words ** 2).sum(1)

    @classmethod
    def learn(cls, descriptors: list[np.ndarray], n_words: int, seed: int = 0) -> "Vocabulary | None":
        """k-means over the keyframes' descriptors (a list of ``[N_i, 32]`` uint8), idf over those keyframes;
        None when there are fewer descriptors than words."""
        import cv2

        bits = np.concatenate([unpack(d) for d in descriptors if len(d)], 0) if descriptors else np.zeros((0, 256))
        if len(bits) < n_words:
            return None
        cv2.setRNGSeed(int(seed))
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-3)
        _, _, centres = cv2.kmeans(bits.astype(np.float32), n_words, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
        voc = cls(centres, np.ones(n_words, np.float32))
        seen = np.zeros(n_words)
        for d in descriptors:
            seen += np.bincount(voc.assign(d), minlength=n_words) > 0
        voc.idf = np.log((len(descriptors) + 1.0) / (seen + 1.0)).astype(np.float32) + 1e-3
        return voc

    def assign(self, descriptors: np.ndarray) -> np.ndarray:
        """``[N]`` the nearest word of each descriptor."""
        if len(descriptors) == 0:
            return np.zeros(0, int)
        x = unpack(descriptors)
        return np.argmin(self._norm2[None] - 2.0 * x @ self.words.T, axis=1)

    def histogram(self, descriptors: np.ndarray) -> np.ndarray:
        """``[K]`` L2-normalised tf-idf word histogram of ``descriptors [N, 32]``."""
        h = np.bincount(self.assign(descriptors), minlength=len(self.words)).astype(np.float32) * self.idf
        n = np.linalg.norm(h)
        return h / n if n > 0 else h

    def state_dict(self) -> dict:
        import torch

        return {"words": torch.from_numpy(self.words.copy()), "idf": torch.from_numpy(self.idf.copy())}

    @classmethod
    def from_state_dict(cls, d: dict) -> "Vocabulary":
        return cls(d["words"].numpy(), d["idf"].numpy())
