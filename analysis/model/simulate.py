"""Transient simulation of an impact on a structure with grounded nonlinear springs.

The structure is reduced to its modes below a stated cutoff plus residual-flexibility vectors at the
hammer and spring DOFs (:mod:`analysis.model.reduction`); the reduced equations are stepped with an
energy-conserving implicit midpoint scheme (:mod:`analysis.model._integrator`). Results carry the
responses at the requested output DOFs and the ground truth the analysis is judged against: linear
modal coordinates, modal energies and the energy budget.

Choices (documented in ``docs/simulator.md``):

* **Cutoff**: 5 kHz by default — three times the main lobe of a 1 ms hammer pulse (1.5 kHz) and well
  above the 1 kHz band of the seed's analysis. Tested: doubling it changes the response by < 0.5 %.
* **Sub-steps** per output sample, chosen per output interval: enough that ``omega_eff dt <=
  max_omega_dt``, where ``omega_eff^2`` is the top kept mode's ``omega^2`` plus each spring's current
  tangent stiffness times its squared basis row — an upper bound on the top frequency of the
  linearised system. A linear or weakly nonlinear run uses the kept-mode count throughout (8 per
  sample at 16384 Hz for a 5 kHz cutoff); a hit that drives a cubic spring hard gets as many
  sub-steps as its instantaneous stiffness needs, up to ``max_substeps`` per sample (hits on that cap
  are counted in the result, never silent). The midpoint rule's frequency error is
  ``(omega dt)^2 / 12`` (0.5 % at 0.25); ``order=4`` composes three stages into a 4th-order step.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from analysis.model._integrator import integrate_batch_moments, integrate_batch_record, state_size
from analysis.model.beam import FloatArray
from analysis.model.forces import Force, ForceSeries, HalfSine
from analysis.model.modal import Modes, structure_modes
from analysis.model.nonlinear import incidence
from analysis.model.reduction import ReducedModel, reduce_for_simulation
from analysis.model.structure import Structure

DEFAULT_CUTOFF_HZ = 5000.0
DEFAULT_MAX_OMEGA_DT = 0.25
DEFAULT_ORDER = 2

# Yoshida's triple jump: three midpoint stages of h*g1, h*g2, h*g1 make a symmetric 4th-order step.
_CBRT2 = 2.0 ** (1.0 / 3.0)
_YOSHIDA = np.array([1.0 / (2.0 - _CBRT2), -_CBRT2 / (2.0 - _CBRT2), 1.0 / (2.0 - _CBRT2)])


@dataclass(frozen=True)
class EnergyBudget:
    """Energies (J) at every output sample, shape (batch, n_samples).

    ``input_work - dissipated == kinetic + potential_linear + potential_nonlinear`` holds to rounding
    for the discrete scheme (see ``_integrator``); ``dissipated`` counts the modal damping and the rig's
    ``[[dampers]]`` (viscous and Coulomb work, eq. 5.11).
    """

    kinetic: FloatArray
    potential_linear: FloatArray
    potential_nonlinear: FloatArray
    dissipated: FloatArray
    input_work: FloatArray

    @property
    def total(self) -> FloatArray:
        """Mechanical energy stored in the structure."""
        return self.kinetic + self.potential_linear + self.potential_nonlinear

    @property
    def closure_error(self) -> FloatArray:
        """``input_work - dissipated - total`` (J); zero for an exact budget."""
        return self.input_work - self.dissipated - self.total


@dataclass(frozen=True)
class SimulationResult:
    """A batch of impact responses sampled at ``sample_rate``; the first axis is the batch."""

    t: FloatArray
    sample_rate: float
    amplitudes: FloatArray
    force: FloatArray  # (B, n) N, at the sample instants
    output_names: tuple[str, ...]
    displacement: FloatArray  # (B, n, n_out) m
    velocity: FloatArray  # (B, n, n_out) m/s
    acceleration: FloatArray  # (B, n, n_out) m/s^2
    modal_q: FloatArray  # (B, n, n_modes) linear modal coordinates (mass-normalised modes)
    modal_v: FloatArray  # (B, n, n_modes)
    mode_omega: FloatArray  # (n_modes,) rad/s
    energy: EnergyBudget
    steps_per_sample: FloatArray  # (B,) mean integration steps per output sample actually taken
    substep_cap_hits: FloatArray  # (B,) output intervals that needed more than max_substeps
    first_index: int = 0  # the first sample's index on the run's clock (a segment of ImpactSimulator.run_segments)

    @property
    def mode_frequencies_hz(self) -> FloatArray:
        return self.mode_omega / (2.0 * np.pi)

    @cached_property
    def modal_energy(self) -> FloatArray:
        """Linear modal energies ``(q'^2 + omega^2 q^2) / 2`` (J), shape (B, n, n_modes)."""
        return 0.5 * (self.modal_v**2 + (self.mode_omega**2) * self.modal_q**2)


@dataclass(frozen=True)
class MomentResult:
    """What an RQ-FEP needs from each run without keeping the time series (seed §4.2).

    ``mean`` (B, n_out) and ``covariance`` (B, n_out, n_out, 1/n-normalised as eq. 2.12) of the
    output displacements over the output samples, and the input work (J) — the seed's energy axis.
    """

    amplitudes: FloatArray
    mean: FloatArray
    covariance: FloatArray
    input_work: FloatArray
    dissipated: FloatArray
    n_samples: int
    output_names: tuple[str, ...]
    steps_per_sample: FloatArray
    substep_cap_hits: FloatArray


class ImpactSimulator:
    """Simulate hammer impacts on ``structure`` at ``force_dof``, observed at ``output_dofs``.

    Built once per structure (modal analysis and reduction are cached); ``run`` and ``run_moments``
    take a batch of force amplitudes in one call.
    """

    def __init__(
        self,
        structure: Structure,
        force_dof: int,
        output_dofs: Sequence[int],
        *,
        cutoff_hz: float = DEFAULT_CUTOFF_HZ,
        residual_vectors: bool = True,
        max_omega_dt: float = DEFAULT_MAX_OMEGA_DT,
        order: int = DEFAULT_ORDER,
        max_substeps: int = 4096,
        modes: Modes | None = None,
    ) -> None:
        if order not in (2, 4):
            raise ValueError("order must be 2 (implicit midpoint) or 4 (its triple-jump composition)")
        self.order = order
        if max_substeps < 1:
            raise ValueError("max_substeps must be >= 1")
        self.max_substeps = int(max_substeps)
        if not 0 <= force_dof < structure.n_dof:
            raise ValueError(f"force DOF {force_dof} outside the structure's {structure.n_dof} DOFs")
        self.structure = structure
        self.force_dof = int(force_dof)
        self.output_dofs = [int(i) for i in output_dofs]
        self.max_omega_dt = float(max_omega_dt)
        self.modes = modes if modes is not None else structure_modes(structure)
        self.reduced: ReducedModel = reduce_for_simulation(
            structure, cutoff_hz, [self.force_dof], residual_vectors=residual_vectors, modes=self.modes
        )
        red = self.reduced
        self._omega2 = np.ascontiguousarray(red.omega**2)
        self._cdamp = np.ascontiguousarray(red.damping)
        self._phi_f = np.ascontiguousarray(red.basis[self.force_dof])
        nl = red.nonlinear
        # The integrator's local-force rows: the springs, then each damper's viscous and Coulomb rows (same
        # incidence; a row's force depends on its stretch over the step, nonlinear._dg), so damping and friction
        # enter the midpoint step exactly where the spring forces do.
        damp_rows = [(d, row) for d in red.dampers for row in d.rows()]
        ends = [*nl, *(d for d, _ in damp_rows)]
        self._B = np.ascontiguousarray((incidence(ends, structure.n_dof) @ red.basis).reshape(len(ends), red.n_basis))
        self._law = np.array([s.code for s in nl] + [r[0] for _, r in damp_rows], dtype=np.int64)
        self._kc = np.array([s.coefficient for s in nl] + [r[1] for _, r in damp_rows], dtype=float)
        self._pe = np.array([s.exponent for s in nl] + [r[2] for _, r in damp_rows], dtype=float)
        self._phi_out = red.rows(self.output_dofs)

    @property
    def feedthrough(self) -> FloatArray:
        """Acceleration at each output per newton at the force DOF, the instantaneous part: every basis vector's
        acceleration holds ``phi_F F(t)`` (the rest is an integral of the force). A DAQ filter treats this part of
        an accelerometer's signal as it treats the hammer's (analysis.model.antialias)."""
        return self._phi_out @ self._phi_f

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(self.structure.dofs[i].name for i in self.output_dofs)

    def steps_per_sample(self, sample_rate: float) -> int:
        om_max = float(self.reduced.omega[self.reduced.n_modes - 1])
        return max(1, int(np.ceil(om_max / (sample_rate * self.max_omega_dt))))

    @staticmethod
    def n_samples(duration: float, sample_rate: float) -> int:
        """Output samples of a run: a record of D seconds holds D * fs samples at t = k / fs (the DAQ's
        sample-exact contract), at least two."""
        return max(2, round(duration * sample_rate))

    def _prepare(self, force: Force, duration: float, sample_rate: float, amplitudes: Sequence[float] | None):
        if sample_rate <= 0:
            raise ValueError("sample rate must be positive")
        if duration <= 0:
            raise ValueError("duration must be positive")
        n_samples = self.n_samples(duration, sample_rate)
        n_min = min(self.steps_per_sample(sample_rate), self.max_substeps)
        gammas = _YOSHIDA.copy() if self.order == 4 else np.array([1.0])
        om_base = float(self.reduced.omega[self.reduced.n_modes - 1])
        stepping = (gammas, 1.0 / sample_rate, n_min, self.max_substeps, om_base**2, self.max_omega_dt)
        if isinstance(force, HalfSine):
            fdesc = (0, float(force.start), float(force.duration), np.zeros(2), np.zeros(2), np.zeros(2))
        elif isinstance(force, ForceSeries):
            tt = np.ascontiguousarray(force.t, dtype=float)
            ff = np.ascontiguousarray(force.force, dtype=float)
            cum = np.concatenate([[0.0], np.cumsum(0.5 * (ff[1:] + ff[:-1]) * np.diff(tt))])
            fdesc = (1, 0.0, 1.0, tt, ff, cum)
        else:
            raise TypeError(f"unsupported force {type(force).__name__}")
        model = (self._omega2, self._cdamp, self._phi_f, self._B, self._law, self._kc, self._pe)
        amps = np.atleast_1d(np.asarray([force.peak] if amplitudes is None else amplitudes, dtype=float))
        return n_samples, model, fdesc, stepping, amps

    def run(
        self, force: Force, duration: float, sample_rate: float, amplitudes: Sequence[float] | None = None
    ) -> SimulationResult:
        """Full time histories for each amplitude (``force`` is scaled so its peak is the amplitude)."""
        n, model, fdesc, stepping, amps = self._prepare(force, duration, sample_rate, amplitudes)
        state = np.zeros((amps.size, state_size(model[0].shape[0], model[3].shape[0])))
        return self._record(force, sample_rate, amps, model, fdesc, stepping, 0, n, state)

    def run_segments(
        self,
        force: Force,
        duration: float,
        sample_rate: float,
        amplitudes: Sequence[float] | None = None,
        segment: int = 16384,
    ) -> Iterator[SimulationResult]:
        """:meth:`run` in consecutive pieces of ``segment`` output samples (the last one shorter), each a
        :class:`SimulationResult` of its samples with ``first_index`` and ``t`` on the whole run's clock, so
        memory is bounded by one segment however long the run. The integrator continues from the state at
        the end of the previous piece and takes the same steps as one call (analysis.model._integrator), so
        the pieces are the samples of :meth:`run` (bit for bit in the integrator's state, tested).
        ``steps_per_sample`` counts the segment's own output intervals."""
        if segment < 1:
            raise ValueError("segment must be >= 1 sample")
        n, model, fdesc, stepping, amps = self._prepare(force, duration, sample_rate, amplitudes)
        state = np.zeros((amps.size, state_size(model[0].shape[0], model[3].shape[0])))
        for n0 in range(0, n, segment):
            yield self._record(force, sample_rate, amps, model, fdesc, stepping, n0, min(segment, n - n0), state)

    def _record(self, force: Force, sample_rate: float, amps: FloatArray, model, fdesc, stepping, n0: int, m: int,
                state: FloatArray) -> SimulationResult:  # fmt: skip
        """Output samples ``n0 .. n0 + m - 1`` continuing from ``state`` (updated in place) and what follows
        from them: forces, output responses, accelerations, modal coordinates and the energy budget."""
        q, v, g, work, diss, steps, capped = integrate_batch_record(amps, model, fdesc, stepping, m, n0, state)
        t = np.arange(n0, n0 + m) / sample_rate
        f_t = amps[:, None] * force.shape_at(t)[None, :]
        # Accelerations from the equations of motion at the sample instants.
        acc_q = f_t[:, :, None] * self._phi_f - self._cdamp * v - self._omega2 * q
        if self._B.shape[0]:
            acc_q -= g @ self._B
        P = self._phi_out.T
        pe_nl = np.zeros_like(work)
        if self._B.shape[0]:
            w = q @ self._B.T
            for i, spring in enumerate(self.reduced.nonlinear):  # the damper rows after them store no energy
                pe_nl += spring.potential(w[..., i])
        energy = EnergyBudget(
            kinetic=0.5 * np.sum(v**2, axis=-1),
            potential_linear=0.5 * np.sum(self._omega2 * q**2, axis=-1),
            potential_nonlinear=pe_nl,
            dissipated=diss,
            input_work=work,
        )
        nm = self.reduced.n_modes
        return SimulationResult(
            t=t,
            sample_rate=float(sample_rate),
            amplitudes=amps,
            force=f_t,
            output_names=self.output_names,
            displacement=q @ P,
            velocity=v @ P,
            acceleration=acc_q @ P,
            modal_q=q[..., :nm],
            modal_v=v[..., :nm],
            mode_omega=self.reduced.omega[:nm].copy(),
            energy=energy,
            steps_per_sample=steps / max(1, m - 1 if n0 == 0 else m),
            substep_cap_hits=capped,
            first_index=n0,
        )

    def run_moments(self, force: Force, duration: float, sample_rate: float, amplitudes: Sequence[float]) -> MomentResult:
        """Mean and covariance of the output displacements per amplitude, in bounded memory.

        Moments are accumulated in the reduced coordinates (``n_basis`` squared per run) and mapped to
        the outputs at the end: ``cov_x = P cov_q P^T`` is exact for the linear map ``x = P q``.
        """
        n, model, fdesc, stepping, amps = self._prepare(force, duration, sample_rate, amplitudes)
        sq, sqq, work, diss, steps, capped = integrate_batch_moments(amps, model, fdesc, stepping, n)
        return MomentResult(**self.moment_fields(amps, n, sq, sqq, work, diss, steps, capped))

    def moment_fields(
        self, amps: FloatArray, n: int, sq: FloatArray, sqq: FloatArray, work: FloatArray, diss: FloatArray,
        steps: FloatArray, capped: FloatArray,
    ) -> dict:  # fmt: skip
        """The :class:`MomentResult` fields from per-run sums ``Σq`` (B, r) and ``Σqqᵀ`` (B, r, r) over ``n``
        samples in the reduced coordinates: mean and 1/n covariance mapped to the outputs (exact for the
        linear map ``x = P q``). Shared with the sweep's modal-phase runs (analysis.model.sweep)."""
        mq = sq / n
        cq = sqq / n - mq[:, :, None] * mq[:, None, :]
        P = self._phi_out
        return {
            "amplitudes": amps, "mean": mq @ P.T, "covariance": np.einsum("ir,brs,js->bij", P, cq, P),
            "input_work": work, "dissipated": diss, "n_samples": n, "output_names": self.output_names,
            "steps_per_sample": steps / (n - 1), "substep_cap_hits": capped,
        }  # fmt: skip
