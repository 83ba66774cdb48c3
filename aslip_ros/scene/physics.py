"""The sound model: slip, handling and robot noise at every microphone, block by block.

Physics-light on purpose (shared/docs/scene-physics.md): each term exists because an
ablation in ``scene/ablation.py`` shows a result that depends on it (docs/scene.md).

- Slip source per finger: broadband friction noise whose level grows as ``speed**0.75`` and
  whose spectrum brightens with speed, plus, on a textured pad, two ridge families (normals
  x and z, different periods and duty cycles) that add harmonic lines at ``|v.n| / lambda``.
  The lines give the slip axis; their odd-only versus full harmonic series tells the two
  families apart.
- The source sits towards the leading edge of the contact, so microphones nearer that edge
  hear it louder (distance falloff); that level pattern is the only sign cue.
- Rotational slip about the pad normal (``w_rel``): each microphone's source follows the local
  slip velocity of the pad region it hears, ``v + w x r`` at its position, with the same ridge
  physics and its own line phases; the spread of velocities over that region (its RMS radius
  ``heard_radius_m``) adds broadband but no lines, so even a microphone at the pad centre hears
  a turning object. The leading-edge shift follows the translational part only.
- Nuisances that make detection near the slip threshold honest: slow normal-force variation,
  per-grasp coupling of each microphone (gain mismatch, and the hand's own path to it),
  stick-slip and handling clicks, handling noise without slip, and a microphone noise floor.
- Robot operating noise: nearly common mode (its own +-1 dB path per microphone,
  ``robot_path_db``), gear-mesh lines tied to joint speed plus broadband, silent when the
  arm is still.

All random draws come from pages keyed by ``(seed, page index)``, and every filter carries
its state across blocks, so the output does not depend on how the stream is cut into blocks.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .layouts import Layout, ObjectSpec, PadSpec

#: Version of the scene's physics and motion defaults, written into every trial's metadata.
#: Bump it whenever a default changes what the scene renders, so that datasets from older
#: bags can be told apart. 1: the first scene. 2: smooth pads radiate from a spread-out
#: contact (smooth_edge_fraction) and external pushes come closer together. 3: per-grasp
#: coupling on (gain_mismatch_db 3, handling_path_db 1; :data:`UNCOUPLED` renders version 2).
#: 4: rotational slip about the pad normal (twisting pushes with ``twist_fraction``,
#: ``gravity_pivot``, the pivoting wall push); without rotation it renders what 3 rendered.
SCENE_VERSION = 4

#: Noise columns drawn per sample; fixed so one seed gives the same noise for every layout.
_COL_BB_LOW = slice(0, 2)
_COL_BB_HIGH = slice(2, 4)
_COL_FORCE = slice(4, 7)
_COL_JITTER = 7
_COL_HANDLING = 8
_COL_ROBOT = 9
_COL_FLOOR = slice(10, 14)
_COL_WANDER = slice(14, 18)
_N_COLS = 18
_PAGE = 16384
#: Candidate click rate for thinning [1/s]; every modelled click rate stays below it.
_CLICK_MAX_RATE = 400.0


@dataclass(frozen=True)
class Acoustics:
    """Every knob of the sound model (levels are RMS in full-scale units).

    Ablations switch mechanisms off with :func:`dataclasses.replace`, e.g.
    ``replace(Acoustics(), leading_edge_shift_m=0.0)``.
    """

    slip_level: float = 0.02          # broadband RMS at speed_ref, roughness 1
    speed_ref_m_s: float = 0.05
    speed_exponent: float = 0.75      # Ben Abdelounis et al. 2010
    brighten_speed_m_s: float = 0.03  # speed at which high band equals low band
    ridge_period_x_m: float = 0.6e-3  # ridges with normal x
    ridge_period_z_m: float = 1.0e-3  # ridges with normal z
    ridge_duty_x: float = 0.2         # narrow ridges: full harmonic series
    ridge_duty_z: float = 0.5         # square profile: odd harmonics only
    n_harmonics: int = 8
    line_level: float = 1.5           # texture lines relative to broadband
    ridge_jitter: float = 0.03        # relative period spread (line width)
    leading_edge_shift_m: float = 5.0e-3  # source centroid shift towards the leading edge
    smooth_edge_fraction: float = 0.3  # leading-edge shift kept on a smooth pad (diffuse)
    tip_brightness: float = 0.5       # source towards the free fingertip sounds brighter
    contact_wander_m: float = 2.0e-3  # slow wander of each pad's contact centroid (std)
    contact_wander_tau_s: float = 0.5
    falloff_m: float = 10.0e-3        # level ~ 1 / (1 + r / falloff)
    force_var_db: float = 2.0         # slow normal-force variation (std), both pads alike
    force_tau_s: float = 0.4
    gain_mismatch_db: float = 3.0     # per-grasp coupling of each microphone (+-dB; scene.md)
    handling_path_db: float = 1.0     # per-grasp path difference of handling noise (+-dB)
    robot_path_db: float = 1.0        # per-grasp path difference of robot noise (+-dB)
    click_rate_slip_smooth: float = 300.0   # stick-slip clicks per (m/s) per s, smooth pad
    click_rate_slip_textured: float = 60.0
    click_rate_touch: float = 25.0    # handling clicks per second while touched
    click_level: float = 0.03
    handling_level: float = 0.004     # hand on the object, no slip
    robot_level: float = 0.02         # robot noise RMS at joint_speed_ref
    robot_joint_speed_ref: float = 0.25
    floor_rms: float = 3.0e-4         # electronics noise floor per channel
    heard_radius_m: float = 7.0e-3    # RMS radius of the pad region a microphone hears

    def validate(self) -> None:
        """Raise ValueError for a physically meaningless setting."""
        positive = ("speed_ref_m_s", "brighten_speed_m_s", "ridge_period_x_m",
                    "ridge_period_z_m", "falloff_m", "force_tau_s", "robot_joint_speed_ref",
                    "contact_wander_tau_s")
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ValueError(f"Acoustics.{name} must be positive, got {getattr(self, name)}")
        for name, value in vars(self).items():
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"Acoustics.{name} must be finite and >= 0, got {value}")
        if self.smooth_edge_fraction > 1.0:
            raise ValueError("Acoustics.smooth_edge_fraction must lie in [0, 1]")
        if not 0.0 < self.ridge_duty_x < 1.0 or not 0.0 < self.ridge_duty_z < 1.0:
            raise ValueError("ridge duty cycles must lie in (0, 1)")
        if int(self.n_harmonics) != self.n_harmonics or self.n_harmonics < 1:
            raise ValueError("Acoustics.n_harmonics must be a positive integer")


#: The scene without per-grasp coupling (scene version 2's sound): every microphone couples
#: alike in every grasp. For ablations and for comparing with models of that scene.
UNCOUPLED = Acoustics(gain_mismatch_db=0.0, handling_path_db=0.0)


@lru_cache(maxsize=16)
def _filters(fs: float) -> dict:
    """Filters used by the synthesizer, with the RMS gain each has for unit white noise."""
    # scipy.signal (about a second to import) is imported where the scene renders, not with
    # the package: a node that only names the layouts (audio_capture) never needs it.
    from scipy import signal
    nyq = 0.5 * fs

    def band(lo: float, hi: float) -> tuple[np.ndarray, np.ndarray, float]:
        b, a = signal.butter(2, [lo / nyq, min(hi, 0.45 * fs) / nyq], btype="band")
        h = signal.lfilter(b, a, np.r_[1.0, np.zeros(int(fs // 5))])
        return b, a, float(np.sqrt(np.sum(h * h)))

    # A two-pole resonance: the ringing of a pad after a stick-slip or handling click.
    f_click, decay_s = 3000.0, 1.5e-3
    r = np.exp(-1.0 / (decay_s * fs))
    a_click = np.array([1.0, -2.0 * r * np.cos(2 * np.pi * f_click / fs), r * r])
    return {
        "low": band(40.0, 1500.0),
        "high": band(1500.0, 9000.0),
        "handling": band(60.0, 3000.0),
        "robot": band(100.0, 6000.0),
        "click": (np.array([1.0 - r]), a_click),
    }


def _ridge_harmonics(duty: float, n: int) -> np.ndarray:
    """Fourier amplitudes of a rectangular ridge profile, normalised to unit RMS."""
    k = np.arange(1, n + 1)
    amp = np.abs(np.sin(np.pi * k * duty)) / k
    amp[amp < 1e-9] = 0.0
    return amp / np.sqrt(0.5 * np.sum(amp * amp))


def _harmonic_sum(phase: np.ndarray, amp: np.ndarray) -> np.ndarray:
    """``sum_k amp[k-1] * sin(k * phase)`` by the Chebyshev recurrence (one sin, one cos)."""
    p32 = phase.astype(np.float32)      # float32 sin/cos are SIMD: about 10x faster
    s1 = np.sin(p32)
    two_c = 2.0 * np.cos(p32)
    out = amp[0] * s1
    s_prev, s_k = np.zeros_like(s1), s1
    for a in amp[1:]:
        s_prev, s_k = s_k, two_c * s_k - s_prev
        if a != 0.0:
            out += a * s_k
    return out


class NoisePages:
    """Reproducible random draws addressed by absolute sample index, in fixed pages."""

    def __init__(self, seed: int, fs: float) -> None:
        self._seed = int(seed)
        self._fs = float(fs)
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _page(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        page = self._cache.get(k)
        if page is None:
            rng = np.random.default_rng([self._seed, 0x5C3E, k])
            # Uniform white noise scaled to unit variance: 4x cheaper than normals and, once
            # filtered, indistinguishable from Gaussian noise.
            normals = rng.random((_PAGE, _N_COLS), dtype=np.float32)
            normals -= np.float32(0.5)
            normals *= np.float32(np.sqrt(12.0))
            n_ev = rng.poisson(_CLICK_MAX_RATE * _PAGE / self._fs)
            # Candidate clicks: sample position, acceptance draw, log-amplitude, finger.
            events = np.column_stack([
                np.sort(rng.integers(0, _PAGE, n_ev)).astype(float),
                rng.random(n_ev), rng.normal(0.0, 0.5, n_ev), rng.integers(0, 3, n_ev)])
            if len(self._cache) >= 2:
                self._cache.pop(min(self._cache))
            self._cache[k] = page = (normals, events)
        return page

    def get(self, start: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Normals ``(n, cols)`` and candidate events (rows: index-in-block, u, logamp, src)."""
        out = np.empty((n, _N_COLS), dtype=np.float32)
        events = []
        i = start
        while i < start + n:
            k, off = divmod(i, _PAGE)
            take = min(_PAGE - off, start + n - i)
            normals, ev = self._page(k)
            out[i - start:i - start + take] = normals[off:off + take]
            sel = (ev[:, 0] >= off) & (ev[:, 0] < off + take)
            if np.any(sel):
                e = ev[sel].copy()
                e[:, 0] += i - start - off
                events.append(e)
            i += take
        return out, (np.concatenate(events) if events else np.empty((0, 4)))


class Synth:
    """Multi-channel audio for one trial, rendered block by block with continuous state."""

    def __init__(self, layout: Layout, pad: PadSpec, obj: ObjectSpec, acoustics: Acoustics,
                 sample_rate: float, seed: int) -> None:
        acoustics.validate()
        self.layout, self.pad, self.obj, self.ac = layout, pad, obj, acoustics
        self.fs = float(sample_rate)
        self._noise = NoisePages(seed, self.fs)
        rng = np.random.default_rng([int(seed), 0xC0A5])
        c = layout.n_channels
        # Per-trial constants: the sensor coupling changes every time a pad is re-seated.
        self.gain = 10.0 ** (rng.uniform(-1, 1, c) * acoustics.gain_mismatch_db / 20.0)
        # Joint speeds from TCP velocity: a fixed, well-conditioned stand-in for the inverse
        # Jacobian of the pose the arm holds in this trial [rad/s per m/s].
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        self._jac = q * rng.uniform(1.5, 3.5, 3)[:, None]
        # The arm's noise reaches each microphone through its own path too (+-1 dB by
        # default); the same draw for every robot_path_db, so 1 dB renders what it always did.
        self._robot_coupling = 10.0 ** (rng.uniform(-1, 1, c) * acoustics.robot_path_db
                                        / 20.0)
        # The hand reaches each microphone through its own path in the object; drawn from a
        # separate stream so that 0 dB (:data:`UNCOUPLED`) renders exactly what version 2 did.
        path_rng = np.random.default_rng([int(seed), 0x4A7D])
        self._handling_path = (10.0 ** (path_rng.uniform(-1, 1, c) * acoustics.handling_path_db
                                        / 20.0)).astype(np.float32)
        self._mesh_hz = rng.uniform(2800.0, 3600.0, 3)  # gear-mesh Hz per (rad/s) per joint
        self._mic_xz = layout.positions_xz()
        self._mic_finger = layout.finger_index()
        self._harm_x = _ridge_harmonics(acoustics.ridge_duty_x, acoustics.n_harmonics)
        self._harm_z = _ridge_harmonics(acoustics.ridge_duty_z, acoustics.n_harmonics)
        f = _filters(self.fs)
        self._f = f
        # Bound once here, where the scene starts rendering (see _filters), not per block.
        from scipy.signal import lfilter
        self._lfilter = lfilter
        self._zi = {name: np.zeros((max(len(f[name][1]), len(f[name][0])) - 1, cols))
                    for name, cols in (("low", 2), ("high", 2), ("handling", 1),
                                       ("robot", 1), ("click", 3))}
        self._a_force = np.exp(-1.0 / (acoustics.force_tau_s * self.fs))
        self._a_jitter = np.exp(-1.0 / (0.05 * self.fs))
        self._a_wander = np.exp(-1.0 / (acoustics.contact_wander_tau_s * self.fs))
        self._wander_state = rng.standard_normal(4)
        self._force_state = rng.standard_normal(3)
        self._jitter_state = 0.0
        self._phase = rng.uniform(0, 2 * np.pi, 2)          # ridge families x, z
        self._mic_phase: np.ndarray | None = None           # per microphone while turning
        self._robot_phase = rng.uniform(0, 2 * np.pi, 3)    # one per joint
        d = np.hypot(self._mic_xz[:, 0], self._mic_xz[:, 1])
        self._g0 = 1.0 / (1.0 + d / acoustics.falloff_m)

    def _lowpass(self, x: np.ndarray, a: float, state: np.ndarray | float):
        """Unit-variance one-pole low-pass (AR(1)) with carried state."""
        b = np.sqrt(1.0 - a * a)
        zi = np.atleast_1d(np.asarray(state, dtype=float) * a)
        if x.ndim == 2:
            zi = zi[None, :]
        y, _ = self._lfilter([b], [1.0, -a], x, axis=0, zi=zi)
        return y

    def _filt(self, name: str, x: np.ndarray) -> np.ndarray:
        b, a = self._f[name][0], self._f[name][1]
        y, self._zi[name] = self._lfilter(b, a, x, axis=0, zi=self._zi[name])
        return y.astype(np.float32)

    def local_velocities(self, v_rel: np.ndarray, w_rel: np.ndarray) -> np.ndarray:
        """Slip velocity of the pad point under each microphone, ``(n, n_channels, 2)`` [m/s].

        ``v_rel`` (n, 2) is the planar slip velocity at the pad centre (grasp-plane x, z) and
        ``w_rel`` (n,) the angular velocity about the pad normal (+y) [rad/s]; a microphone at
        in-plane ``(x, z)`` sits under ``(vx + wy * z, vz - wy * x)``.
        """
        v = np.asarray(v_rel, dtype=float)
        w = np.asarray(w_rel, dtype=float)
        arm = np.column_stack([self._mic_xz[:, 1], -self._mic_xz[:, 0]])     # (C, 2)
        return v[:, None, :] + w[:, None, None] * arm[None, :, :]

    def render(self, start: int, v_rel: np.ndarray, v_tcp: np.ndarray,
               touch: np.ndarray, w_rel: np.ndarray | None = None) -> np.ndarray:
        """Audio for samples ``start .. start+n`` as float32 ``(n, n_channels)``.

        ``v_rel`` (n, 2): object-relative-to-finger velocity in grasp-plane x, z at the pad
        centre [m/s]; ``v_tcp`` (n, 3): TCP velocity in ``world`` [m/s]; ``touch`` (n,): 0..1,
        an external agent's hand (or a wall) touching the object; ``w_rel`` (n,): angular
        velocity of the object relative to the finger about the pad normal (+y) [rad/s].
        Without rotation (None or all zero) the output is exactly that of scene version 3;
        only blocks that turn take the per-microphone path.
        """
        ac = self.ac
        n = v_rel.shape[0]
        z, events = self._noise.get(start, n)
        f = self._f
        c = self.layout.n_channels
        out = np.zeros((n, c), dtype=np.float32)

        # Slow processes advance in every block, slip or not, so that the output does not
        # depend on where blocks start.
        fz = self._lowpass(z[:, _COL_FORCE], self._a_force, self._force_state)
        self._force_state = fz[-1]
        jit = self._lowpass(z[:, _COL_JITTER], self._a_jitter, self._jitter_state)
        self._jitter_state = float(jit[-1])
        wander = self._lowpass(z[:, _COL_WANDER], self._a_wander, self._wander_state)
        self._wander_state = wander[-1]
        low = self._filt("low", z[:, _COL_BB_LOW])
        high = self._filt("high", z[:, _COL_BB_HIGH])
        speed = np.hypot(v_rel[:, 0], v_rel[:, 1])
        rel_speed = speed / ac.speed_ref_m_s
        w = None if w_rel is None or not np.any(w_rel) else np.asarray(w_rel, dtype=float)
        if w is not None:
            # The pad as a whole slips at the speed a centred microphone hears: the planar
            # part plus the spread of the turning over the region it hears.
            speed = np.sqrt(speed * speed + (w * ac.heard_radius_m) ** 2)

        # Clicks by thinning page-drawn candidates: slip (per finger) and handling (common).
        impulses = np.zeros((n, 3), dtype=np.float32)
        if events.shape[0]:
            slip_rate = (ac.click_rate_slip_textured if self.pad.textured
                         else ac.click_rate_slip_smooth) * speed
            idx = events[:, 0].astype(int)
            srcs = events[:, 3].astype(int)
            rate = np.where(srcs < 2, 0.5 * slip_rate[idx], ac.click_rate_touch * touch[idx])
            keep = events[:, 1] < rate / _CLICK_MAX_RATE
            impulses[idx[keep], srcs[keep]] = ac.click_level * np.exp(events[keep, 2]) * 40.0
        clicks = self._filt("click", impulses)

        if w is not None:
            out += self._slip_turning(v_rel, w, fz, jit, wander, low, high, clicks)
        elif np.any(speed > 0.0):
            self._mic_phase = None
            out += self._slip(v_rel, speed, rel_speed, fz, jit, wander, low, high, clicks)

        # Handling noise reaches both pads through the object alike: no direction cue.
        hand = self._filt("handling", z[:, _COL_HANDLING:_COL_HANDLING + 1])
        if np.any(touch > 0.0) or np.any(impulses[:, 2]):
            out += (((ac.handling_level / f["handling"][2]) * touch[:, None]) * hand
                    + clicks[:, 2:3]) * self._handling_path

        out += self._robot(z, v_tcp)
        out *= self.gain.astype(np.float32)
        out += np.float32(ac.floor_rms) * z[:, _COL_FLOOR][:, :c]
        return out

    def _slip(self, v_rel, speed, rel_speed, fz, jit, wander, low, high,
              clicks) -> np.ndarray:
        """The slip source heard at every microphone, ``(n, n_channels)``."""
        ac, fs, f = self.ac, self.fs, self._f
        unit = v_rel / np.maximum(speed, 1e-9)[:, None]
        # Normal force: the object is squeezed between the pads, so both feel the same force;
        # a small per-pad part stands for contact quality.
        force_db = ac.force_var_db * (0.97 * fz[:, :1] + 0.25 * fz[:, 1:3])
        amp = (ac.slip_level * self.obj.roughness * rel_speed ** ac.speed_exponent)[:, None]
        amp = (amp * 10.0 ** (force_db / 20.0)).astype(np.float32)       # (n, 2 fingers)

        # Broadband friction noise; faster sliding and rougher objects sound brighter. The
        # finger is clamped at its base and free at its tip, so a source pushed towards the
        # tip (+x) rings brighter than one towards the base: a weak x-sign cue that needs no
        # baseline (even one centred microphone hears it) and that broadband robot noise masks.
        w = speed / (speed + ac.brighten_speed_m_s) * (0.5 + self.obj.brightness)
        w = np.clip(w * (1.0 + ac.tip_brightness * unit[:, 0]), 0.0, 0.95)[:, None]
        src = (np.sqrt(1.0 - w) / f["low"][2]).astype(np.float32) * low \
            + (np.sqrt(w) / f["high"][2]).astype(np.float32) * high

        if self.pad.textured and ac.line_level > 0.0:
            scale = (1.0 + ac.ridge_jitter * jit) * (2.0 * np.pi / fs)
            inc = np.column_stack([np.abs(v_rel[:, 0]) / ac.ridge_period_x_m,
                                   np.abs(v_rel[:, 1]) / ac.ridge_period_z_m]) * scale[:, None]
            ph = self._phase + np.cumsum(inc, axis=0)
            self._phase = np.mod(ph[-1], 2.0 * np.pi)
            lines = _harmonic_sum(ph[:, 0], self._harm_x) * np.abs(unit[:, 0])
            lines += _harmonic_sum(ph[:, 1], self._harm_z) * np.abs(unit[:, 1])
            src += (ac.line_level * lines)[:, None].astype(np.float32)
        src = amp * src + clicks[:, :2] * np.minimum(rel_speed, 1.0)[:, None].astype(np.float32)

        return src[:, self._mic_finger] * self._edge_gain(unit, speed, wander)

    def _edge_gain(self, unit: np.ndarray, speed: np.ndarray, wander: np.ndarray) -> np.ndarray:
        """Level of the slip source at each microphone, float32 ``(n, n_channels)``.

        Leading-edge source: the level at each microphone falls with its distance to it.
        The contact centroid of each pad also wanders slowly (grasp pose, pressure
        distribution), which blurs that level pattern like a real pad does.
        On a smooth pad detachment fronts sweep the whole contact, so the radiating region
        stays spread out; ridges concentrate it at the leading edge (textured pads).
        ``unit`` and ``speed`` are those of the planar slip at the pad centre: a turning
        contact has no leading edge of its own.
        """
        ac = self.ac
        shift = ac.leading_edge_shift_m * (1.0 if self.pad.textured else ac.smooth_edge_fraction)
        centre = unit * (shift * np.minimum(speed / 2e-3, 1.0))[:, None]
        wx = ac.contact_wander_m * wander[:, 0:2][:, self._mic_finger]
        wz = ac.contact_wander_m * wander[:, 2:4][:, self._mic_finger]
        dx = self._mic_xz[None, :, 0] - centre[:, None, 0] - wx
        dz = self._mic_xz[None, :, 1] - centre[:, None, 1] - wz
        g = (1.0 / (1.0 + np.hypot(dx, dz) / ac.falloff_m)) / self._g0    # (n, C)
        return g.astype(np.float32)

    def _slip_turning(self, v_rel, w, fz, jit, wander, low, high, clicks) -> np.ndarray:
        """The slip heard at every microphone while the object turns, ``(n, n_channels)``.

        The same physics as :meth:`_slip`, per microphone: level, brightness and ridge lines
        follow the local slip velocity ``v_m`` under it. Over the region it hears (RMS radius
        ``heard_radius_m``) the turning spreads the velocities by ``|w| * heard_radius_m``
        around ``v_m``: that incoherent part raises the level and the broadband noise but no
        line (its line frequencies smear), so the lines carry the share ``|v_m . n| / s``
        of the effective speed ``s = sqrt(|v_m|^2 + (w * heard_radius_m)^2)``.
        """
        ac, fs, f, fing = self.ac, self.fs, self._f, self._mic_finger
        v_m = self.local_velocities(v_rel, w)                                 # (n, C, 2)
        s = np.sqrt(np.sum(v_m * v_m, axis=2) + ((w * ac.heard_radius_m) ** 2)[:, None])
        coh = v_m / np.maximum(s, 1e-9)[:, :, None]                           # (n, C, 2)
        rel = s / ac.speed_ref_m_s
        force_db = ac.force_var_db * (0.97 * fz[:, :1] + 0.25 * fz[:, 1:3])
        amp = (ac.slip_level * self.obj.roughness * rel ** ac.speed_exponent
               * 10.0 ** (force_db[:, fing] / 20.0)).astype(np.float32)     # (n, C)
        b = s / (s + ac.brighten_speed_m_s) * (0.5 + self.obj.brightness)
        b = np.clip(b * (1.0 + ac.tip_brightness * coh[:, :, 0]), 0.0, 0.95)
        src = (np.sqrt(1.0 - b) / f["low"][2]).astype(np.float32) * low[:, fing] \
            + (np.sqrt(b) / f["high"][2]).astype(np.float32) * high[:, fing]
        if self.pad.textured and ac.line_level > 0.0:
            # Each microphone's lines keep their own phase while the object turns; they start
            # from the shared phase, and the first microphone's carries on after the turn.
            if self._mic_phase is None:
                self._mic_phase = np.tile(self._phase, (len(fing), 1))
            scale = (1.0 + ac.ridge_jitter * jit) * (2.0 * np.pi / fs)
            inc = np.abs(v_m) / np.array([ac.ridge_period_x_m, ac.ridge_period_z_m]) \
                * scale[:, None, None]
            ph = self._mic_phase + np.cumsum(inc, axis=0)
            self._mic_phase = np.mod(ph[-1], 2.0 * np.pi)
            self._phase = self._mic_phase[0].copy()
            lines = _harmonic_sum(ph[:, :, 0], self._harm_x) * np.abs(coh[:, :, 0])
            lines += _harmonic_sum(ph[:, :, 1], self._harm_z) * np.abs(coh[:, :, 1])
            src += (ac.line_level * lines).astype(np.float32)
        src = amp * src + clicks[:, fing] * np.minimum(rel, 1.0).astype(np.float32)
        speed = np.hypot(v_rel[:, 0], v_rel[:, 1])
        unit = v_rel / np.maximum(speed, 1e-9)[:, None]
        return src * self._edge_gain(unit, speed, wander)

    def _robot(self, z: np.ndarray, v_tcp: np.ndarray) -> np.ndarray:
        """Common-mode robot operating noise: gear-mesh lines and broadband, 0 when still."""
        ac = self.ac
        robot_bb = self._filt("robot", z[:, _COL_ROBOT:_COL_ROBOT + 1])
        if ac.robot_level <= 0.0 or not np.any(v_tcp):
            return np.zeros((v_tcp.shape[0], 1), dtype=np.float32)
        qd = np.abs(v_tcp @ self._jac.T)                                   # (n, 3) rad/s
        rel = np.minimum(qd / ac.robot_joint_speed_ref, 2.0)
        # Gear mesh at the joint speed times a mesh constant, and its second harmonic.
        inc = np.minimum(qd * self._mesh_hz, 0.2 * self.fs) * (2.0 * np.pi / self.fs)
        ph = self._robot_phase + np.cumsum(inc, axis=0)
        self._robot_phase = np.mod(ph[-1], 2.0 * np.pi)
        ph32 = ph.astype(np.float32)     # float32 sin/cos are SIMD: about 10x faster
        s1, c1 = np.sin(ph32), np.cos(ph32)
        lines = np.sum(rel * s1 * (1.0 + c1), axis=1, keepdims=True)   # sin + 0.5 sin(2x)
        level = np.sqrt(np.mean(rel * rel, axis=1, keepdims=True))
        bb = robot_bb / self._f["robot"][2] * level
        return (ac.robot_level * (0.6 * lines / 3.0 + bb)
                * self._robot_coupling).astype(np.float32)
