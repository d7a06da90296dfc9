"""Source-filter formant speech synthesis of a phone sequence.

Glottal pulses (pitch contour, jitter) and aspiration through a cascade of
time-varying formant resonators, plus band-passed frication and stop bursts.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import butter, lfilter, sosfilt

from stages.synthetic_speaker import language

FILTER_BLOCK = 80
"""Audio samples per block with constant formant-filter coefficients."""

STOP_CLOSURE_FRACTION = 0.6
"""Fraction of a stop's duration spent in silent (or voice-bar) closure."""

FORMANT_BANDWIDTHS = (90.0, 110.0, 170.0)
FIXED_HIGHER_FORMANTS = ((3400.0, 250.0), (4400.0, 300.0))


def stop_phases(phones: np.ndarray, index: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closure and 12-ms burst masks of a stop, for control samples inside phone ``index``.

    Returns
    -------
    closure, burst : ndarray, (n,) bool
        Closure: the first ``STOP_CLOSURE_FRACTION`` of the unit; burst: the
        12 ms after it. The rest of the unit is the release (aspiration or voicing).
    """
    start, end = phones["start"][index], phones["end"][index]
    release = start + STOP_CLOSURE_FRACTION * (end - start)
    return times < release, (times >= release) & (times < release + 0.012)


def control_tracks(phones: np.ndarray, n_control: int) -> dict[str, np.ndarray]:
    """Step-wise synthesis controls at ``CONTROL_RATE``.

    Returns
    -------
    dict of ndarray
        ``formants`` (n, 3) Hz; ``voicing`` (n,) glottal amplitude; ``aspiration``
        (n,) noise into the vocal tract; one ``noise:<label>`` (n,) frication/burst
        amplitude per unit with a noise band.
    """
    times = np.arange(n_control) / language.CONTROL_RATE
    index = language.phone_index_at(phones, times)
    labels = phones["label"][index]
    tracks = {
        "formants": np.array([language.PHONES[label].formants for label in labels], dtype=np.float64),
        "voicing": np.array([language.PHONES[label].voicing for label in labels]),
        "aspiration": np.zeros(n_control),
    }
    for label, phone in language.PHONES.items():
        if phone.noise_band is not None:
            tracks["noise:" + label] = np.where(labels == label, phone.noise_amp, 0.0)
    closure, burst = stop_phases(phones, index, times)
    for label in ("p", "b", "t", "k"):
        stop = labels == label
        release = stop & ~closure & ~burst
        tracks["noise:" + label] = np.where(stop & burst, language.PHONES[label].noise_amp, 0.0)
        if label == "b":
            tracks["voicing"][release] = 0.6
        else:
            tracks["voicing"][stop] = 0.0
            tracks["aspiration"][release] = 0.12
    return tracks


def pitch_contour(phones: np.ndarray, stressed: np.ndarray, rng: np.random.Generator,
                  n_control: int) -> np.ndarray:
    """Fundamental frequency (Hz) at ``CONTROL_RATE``.

    Per phrase: declination from ~130 to ~105 Hz, a pitch accent on each stressed
    vowel, a slow wobble, and 1 % jitter every 5 ms.
    """
    times = np.arange(n_control) / language.CONTROL_RATE
    f0 = np.full(n_control, 110.0)
    speech = phones["label"] != "sil"
    edges = np.flatnonzero(np.diff(np.concatenate([[0], speech.astype(int), [0]])))
    for first, last in zip(edges[::2], edges[1::2] - 1):
        start, end = phones["start"][first], phones["end"][last]
        inside = (times >= start - 0.05) & (times <= end + 0.05)
        fraction = np.clip((times[inside] - start) / (end - start), 0, 1)
        f_start, f_end = rng.uniform(122, 140), rng.uniform(98, 110)
        f0[inside] = f_start + (f_end - f_start) * fraction
    for center in 0.5 * (phones["start"][stressed] + phones["end"][stressed]):
        f0 += rng.uniform(8, 18) * np.exp(-0.5 * ((times - center) / 0.07) ** 2)
    f0 += 2.0 * np.sin(2 * np.pi * rng.uniform(2, 4) * times + rng.uniform(0, 2 * np.pi))
    jitter = np.repeat(rng.normal(0, 0.01, size=n_control // 5 + 1), 5)[:n_control]
    return f0 * (1.0 + jitter)


def glottal_source(f0: np.ndarray, sample_rate: int) -> np.ndarray:
    """Differentiated Rosenberg glottal pulse train (includes lip radiation).

    Parameters
    ----------
    f0 : ndarray, (N,)
        Fundamental frequency per sample (Hz).

    Returns
    -------
    ndarray, (N,)
        Roughly unit-peak excitation.
    """
    phase = np.mod(np.cumsum(f0 / sample_rate), 1.0)
    rise, fall = 0.4, 0.16
    flow = np.where(phase < rise, 0.5 * (1 - np.cos(np.pi * phase / rise)),
                    np.where(phase < rise + fall, np.cos(0.5 * np.pi * (phase - rise) / fall), 0.0))
    derivative = np.diff(flow, prepend=0.0)
    return derivative / (np.abs(derivative).max() + 1e-12)


def resonator_coefficients(freq: float, bandwidth: float, sample_rate: int) -> tuple[float, float, float]:
    """Klatt resonator ``y[n] = a x[n] + b y[n-1] + c y[n-2]`` with unit DC gain."""
    c = -np.exp(-2 * np.pi * bandwidth / sample_rate)
    b = 2 * np.exp(-np.pi * bandwidth / sample_rate) * np.cos(2 * np.pi * freq / sample_rate)
    return 1.0 - b - c, b, c


def time_varying_resonator(signal: np.ndarray, freqs: np.ndarray, bandwidth: float,
                           sample_rate: int) -> np.ndarray:
    """Second-order resonator whose centre frequency changes every ``FILTER_BLOCK`` samples.

    Parameters
    ----------
    signal : ndarray, (N,)
    freqs : ndarray, (ceil(N / FILTER_BLOCK),)
        Centre frequency (Hz) per block.
    bandwidth : float
        Hz.

    Returns
    -------
    ndarray, (N,)
    """
    output = np.empty_like(signal)
    previous, before_previous = 0.0, 0.0
    for block, freq in enumerate(freqs):
        piece = slice(block * FILTER_BLOCK, (block + 1) * FILTER_BLOCK)
        a, b, c = resonator_coefficients(freq, bandwidth, sample_rate)
        state = [b * previous + c * before_previous, c * previous]
        output[piece], _ = lfilter([a], [1.0, -b, -c], signal[piece], zi=state)
        previous = output[piece][-1]
        before_previous = output[piece][-2] if output[piece].size > 1 else previous
    return output


def vocal_tract(excitation: np.ndarray, formants: np.ndarray, sample_rate: int) -> np.ndarray:
    """Cascade of F1-F3 (time-varying) and two fixed higher formants.

    Parameters
    ----------
    excitation : ndarray, (N,)
    formants : ndarray, (ceil(N / FILTER_BLOCK), 3)
        F1-F3 per block (Hz).
    """
    signal = excitation
    for j, bandwidth in enumerate(FORMANT_BANDWIDTHS):
        signal = time_varying_resonator(signal, formants[:, j], bandwidth, sample_rate)
    for freq, bandwidth in FIXED_HIGHER_FORMANTS:
        a, b, c = resonator_coefficients(freq, bandwidth, sample_rate)
        signal = lfilter([a], [1.0, -b, -c], signal)
    return signal


def band_noise(rng: np.random.Generator, band: tuple, n_samples: int, sample_rate: int) -> np.ndarray:
    """Unit-RMS white noise band-passed to ``band`` (Hz)."""
    high = min(band[1], 0.95 * sample_rate / 2)
    sos = butter(4, [band[0], high], btype="bandpass", fs=sample_rate, output="sos")
    noise = sosfilt(sos, rng.standard_normal(n_samples))
    return noise / (noise.std() + 1e-12)


def to_audio_rate(track: np.ndarray, sigma_s: float, n_samples: int, sample_rate: int) -> np.ndarray:
    """Smooth a ``CONTROL_RATE`` track (Gaussian, ``sigma_s`` seconds) and resample it to (n_samples,)."""
    smooth = gaussian_filter1d(track, sigma_s * language.CONTROL_RATE, axis=0, mode="nearest")
    control_times = np.arange(len(track)) / language.CONTROL_RATE
    return np.interp(np.arange(n_samples) / sample_rate, control_times, smooth)


def block_formants(formants: np.ndarray, n_samples: int, sample_rate: int) -> np.ndarray:
    """F1-F3 (Hz) per ``FILTER_BLOCK``, from step targets at ``CONTROL_RATE`` smoothed over 18 ms.

    Returns
    -------
    ndarray, (ceil(n_samples / FILTER_BLOCK), 3)
    """
    smooth = gaussian_filter1d(formants, 0.018 * language.CONTROL_RATE, axis=0, mode="nearest")
    control_times = np.arange(len(formants)) / language.CONTROL_RATE
    block_times = (np.arange(int(np.ceil(n_samples / FILTER_BLOCK))) + 0.5) * FILTER_BLOCK / sample_rate
    return np.stack([np.interp(block_times, control_times, smooth[:, j]) for j in range(3)], axis=1)


def frication(tracks: dict, rng: np.random.Generator, n_samples: int, sample_rate: int) -> np.ndarray:
    """Sum of band-passed noises gated by the fricative and stop-burst amplitude tracks."""
    noise = np.zeros(n_samples)
    for label, phone in language.PHONES.items():
        if phone.noise_band is None or not tracks["noise:" + label].any():
            continue
        sigma_s = 0.002 if phone.kind == "stop" else 0.008
        envelope = to_audio_rate(tracks["noise:" + label], sigma_s, n_samples, sample_rate)
        noise += envelope * band_noise(rng, phone.noise_band, n_samples, sample_rate)
    return noise


def synthesize_speech(phones: np.ndarray, stressed: np.ndarray, rng: np.random.Generator,
                      sample_rate: int, n_samples: int) -> np.ndarray:
    """Speech-like audio for a phone sequence.

    Voiced units: glottal pulses (with pitch contour and jitter) through the
    formant cascade; fricatives and stop bursts: band-passed noise; stops:
    closure, burst and aspiration. Peak-normalised to 0.7.

    Parameters
    ----------
    phones : structured ndarray, (P,)
    stressed : ndarray, (P,) bool
    rng : numpy Generator
    sample_rate : int
        Hz.
    n_samples : int

    Returns
    -------
    ndarray, (n_samples,) float32
        Mono waveform in [-1, 1].
    """
    n_control = int(np.ceil(n_samples / sample_rate * language.CONTROL_RATE)) + 1
    tracks = control_tracks(phones, n_control)
    f0 = to_audio_rate(pitch_contour(phones, stressed, rng, n_control), 0.002, n_samples, sample_rate)
    voicing = to_audio_rate(tracks["voicing"], 0.006, n_samples, sample_rate)
    aspiration = to_audio_rate(tracks["aspiration"], 0.003, n_samples, sample_rate)
    excitation = voicing * glottal_source(f0, sample_rate) + 0.4 * aspiration * rng.standard_normal(n_samples)
    speech = vocal_tract(excitation, block_formants(tracks["formants"], n_samples, sample_rate), sample_rate)
    speech /= np.abs(speech).max() + 1e-12
    speech += frication(tracks, rng, n_samples, sample_rate)
    speech += 3e-4 * rng.standard_normal(n_samples)
    return (0.7 * speech / np.abs(speech).max()).astype(np.float32)
