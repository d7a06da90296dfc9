"""A phone-like synthetic language: unit inventory and random utterances.

Utterances are silence, phrases of (C)V(C) syllables separated by pauses, and
silence, as a structured array of ``(label, start, end)`` tiling the clip.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PhoneType:
    """One phone-like unit of the synthetic language.

    Attributes
    ----------
    kind : str
        "vowel", "nasal", "fricative", "stop" or "silence".
    mouth : tuple of float
        Target (open, width, round); bilabial closures use a negative opening so
        that the smoothed trajectory reaches full closure.
    dominance : float
        Co-articulation weight: how strongly the unit imposes its mouth target.
    formants : tuple of float
        F1, F2, F3 targets (Hz).
    voicing : float
        Glottal source amplitude (0 = voiceless).
    noise_band : tuple of float or None
        Frication / burst noise pass band (Hz).
    noise_amp : float
        Frication (or burst) noise amplitude.
    duration : tuple of float
        Min and max duration (s).
    """

    kind: str
    mouth: tuple
    dominance: float
    formants: tuple
    voicing: float
    noise_band: tuple | None
    noise_amp: float
    duration: tuple


PHONES = {
    "sil": PhoneType("silence", (0.0, 0.0, 0.0), 1.0, (500, 1500, 2500), 0.0, None, 0.0, (0.3, 1.0)),
    "a": PhoneType("vowel", (0.95, 0.15, 0.0), 1.0, (730, 1090, 2440), 1.0, None, 0.0, (0.08, 0.15)),
    "e": PhoneType("vowel", (0.55, 0.50, 0.0), 1.0, (530, 1840, 2480), 0.9, None, 0.0, (0.07, 0.13)),
    "i": PhoneType("vowel", (0.22, 0.90, 0.0), 1.0, (290, 2250, 3000), 0.8, None, 0.0, (0.07, 0.12)),
    "o": PhoneType("vowel", (0.60, -0.35, 0.6), 1.0, (570, 840, 2410), 0.9, None, 0.0, (0.08, 0.14)),
    "u": PhoneType("vowel", (0.20, -0.60, 1.0), 1.0, (320, 870, 2240), 0.8, None, 0.0, (0.07, 0.12)),
    "m": PhoneType("nasal", (-0.30, 0.0, 0.0), 3.0, (250, 1100, 2300), 0.35, None, 0.0, (0.05, 0.09)),
    "n": PhoneType("nasal", (0.18, 0.20, 0.0), 0.4, (250, 1500, 2500), 0.35, None, 0.0, (0.05, 0.08)),
    "f": PhoneType("fricative", (0.06, 0.10, 0.0), 2.0, (400, 1300, 2500), 0.0, (1500, 7500), 0.04, (0.08, 0.12)),
    "s": PhoneType("fricative", (0.10, 0.50, 0.0), 1.0, (400, 1700, 2600), 0.0, (4500, 7800), 0.09, (0.08, 0.13)),
    "sh": PhoneType("fricative", (0.15, -0.20, 0.8), 1.5, (400, 1800, 2500), 0.0, (1900, 4200), 0.1, (0.08, 0.13)),
    "p": PhoneType("stop", (-0.30, 0.0, 0.0), 3.0, (400, 900, 2300), 0.0, (400, 2500), 0.25, (0.07, 0.11)),
    "b": PhoneType("stop", (-0.30, 0.0, 0.0), 3.0, (300, 900, 2300), 0.15, (400, 2000), 0.15, (0.06, 0.09)),
    "t": PhoneType("stop", (0.15, 0.30, 0.0), 0.4, (400, 1700, 2600), 0.0, (3000, 7500), 0.25, (0.06, 0.10)),
    "k": PhoneType("stop", (0.30, 0.10, 0.0), 0.4, (400, 1900, 2400), 0.0, (1200, 3200), 0.25, (0.07, 0.11)),
}

VOWELS = ("a", "e", "i", "o", "u")
VOWEL_WEIGHTS = (0.28, 0.22, 0.20, 0.15, 0.15)
ONSETS = ("m", "n", "f", "s", "sh", "p", "b", "t", "k")
CODAS = ("m", "n", "s", "t", "k")
PHONE_DTYPE = np.dtype([("label", "U3"), ("start", "f8"), ("end", "f8")])

CONTROL_RATE = 1000
"""Sampling rate (Hz) of articulatory control tracks."""


def sample_syllable(rng: np.random.Generator) -> list[str]:
    """A random (C)V(C) syllable as a list of phone labels."""
    syllable = []
    if rng.random() < 0.8:
        syllable.append(str(rng.choice(ONSETS)))
    syllable.append(str(rng.choice(VOWELS, p=VOWEL_WEIGHTS)))
    if rng.random() < 0.3:
        syllable.append(str(rng.choice(CODAS)))
    return syllable


def sample_word(rng: np.random.Generator) -> list[tuple[str, float, bool]]:
    """A random word of 1-3 syllables, first syllable stressed.

    Returns
    -------
    list of (label, duration_s, stressed)
    """
    word = []
    for syllable_index in range(int(rng.integers(1, 4))):
        stressed = syllable_index == 0
        for label in sample_syllable(rng):
            low, high = PHONES[label].duration
            duration = rng.uniform(low, high)
            is_stressed_vowel = stressed and PHONES[label].kind == "vowel"
            word.append((label, duration * (1.3 if is_stressed_vowel else 1.0), is_stressed_vowel))
    return word


def sample_phrase(rng: np.random.Generator, max_seconds: float) -> list[tuple[str, float, bool]]:
    """Connected words (2-6) that fit in ``max_seconds``; the last vowel is lengthened.

    Returns
    -------
    list of (label, duration_s, stressed); empty if not even one word fits.
    """
    phrase: list[tuple[str, float, bool]] = []
    for _ in range(int(rng.integers(2, 7))):
        word = sample_word(rng)
        if sum(d for _, d, _ in phrase + word) * 1.2 > max_seconds:
            break
        phrase += word
    for position in range(len(phrase) - 1, -1, -1):
        label, duration, stressed = phrase[position]
        if PHONES[label].kind == "vowel":
            phrase[position] = (label, duration * 1.4, stressed)
            break
    return phrase


def sample_phone_sequence(rng: np.random.Generator, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Random utterance: silence, phrases separated by 0.3-1 s pauses, silence.

    Parameters
    ----------
    rng : numpy Generator
    seconds : float
        Total duration; the sequence tiles ``[0, seconds]`` exactly.

    Returns
    -------
    phones : structured ndarray, (P,) of ``PHONE_DTYPE``
        Label, start and end time (s) of each unit, "sil" for silence.
    stressed : ndarray, (P,) bool
        Stressed vowels (carry a pitch accent).
    """
    pause_range = PHONES["sil"].duration
    units = [("sil", rng.uniform(0.3, 0.6), False)]
    elapsed = units[0][1]
    while True:
        phrase = sample_phrase(rng, seconds - elapsed - 0.3)
        if not phrase:
            break
        units += phrase
        elapsed += sum(d for _, d, _ in phrase)
        pause = rng.uniform(*pause_range)
        units.append(("sil", pause, False))
        elapsed += pause
        if elapsed >= seconds - 0.6:
            break
    if units[-1][0] != "sil":
        units.append(("sil", 0.0, False))
    bounds = np.concatenate([[0.0], np.cumsum([d for _, d, _ in units])])
    bounds = np.minimum(bounds, seconds)
    bounds[-1] = seconds
    phones = np.zeros(len(units), dtype=PHONE_DTYPE)
    phones["label"] = [label for label, _, _ in units]
    phones["start"], phones["end"] = bounds[:-1], bounds[1:]
    keep = phones["end"] > phones["start"]
    return phones[keep], np.array([s for _, _, s in units], dtype=bool)[keep]


def phone_index_at(phones: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the phone covering each time (s); clamps outside the timeline."""
    index = np.searchsorted(phones["start"], times, side="right") - 1
    return np.clip(index, 0, len(phones) - 1)


def speech_activity(phones: np.ndarray, times: np.ndarray) -> np.ndarray:
    """True where ``times`` (s) fall inside a non-silence unit."""
    return phones["label"][phone_index_at(phones, times)] != "sil"
