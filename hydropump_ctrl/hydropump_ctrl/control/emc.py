"""Embedded Model Control (Canuto) of the pump: flow tracking and load-sensing margin control.

The structure, in the terms of EMC:

- **Embedded model** (:mod:`.embedded`): the discrete-time simplified dynamics from the command
  to the flow (eq. 19 with the spool stroke limit, the falling-flow branch and its zero), with
  a random-walk **disturbance** ``d`` [m^3/s] at the command that collects what the model
  leaves out (gain and shaft-speed errors, leakage, friction), and the known measurement
  **delay** ``t_d`` as a delay line of ``N`` commands. For the margin, the line of eq. 9 with
  the load conductance ``k = mu_u xi_u`` as a second random-walk disturbance; against the
  compensated sections of a load-sensing circuit (``model.load_law: compensated``), whose
  flow does not depend on the margin, the line is an integrator ``C_l d(dp)/dt = q -
  q_load`` and the load flow ``q_load`` [m^3/s] is the random walk.
- **Noise estimator**: static gains on the model error (flow: delayed sample against the
  delayed model; margin: the undelayed pressure difference). The flow estimator runs on the
  delayed time axis, and a predictor rolls the corrected model forward over the ``N`` stored
  commands to the present, so the delay stays out of the estimator's eigenvalues.
- **Control law**: a reference generator (the nominal model driven toward the reference with
  its own eigenvalue, inside the spool stroke limit, and inverted through the branch-aware model
  for the feedforward), state feedback on the predicted tracking error, and cancellation of the
  estimated disturbance. In margin mode the flow target is ``k_hat dp_r^(1/gamma_u)``: the
  load conductance is cancelled, so the loop gain does not depend on the load aperture.
- **Anti-windup**: the embedded model is fed the applied command (after the current range and
  the rate limit); the disturbance does not integrate while the model says it cannot act (spool
  at its stroke limit for a whole step, plate at an end stop) and stays inside
  ``emc.disturbance_max``; the flow target is kept inside the displacement range.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
import math

from hydropump_sim.components.relief import static_flow

from .base import Controller, finite_value
from .design import compensated_estimator_gains, emc_gains, line_estimator_gains
from .embedded import FED_MIN, fed_share, LineModel, PumpModel, trajectory_step
from .schema import ControllerConfig

# Smallest margin the line model works with: 0.1 bar. Below it the load law is laminar
# (dp_cr_u) and the relative estimator would divide by almost nothing.
DP_FLOOR = 1.0e4
Q_FLOOR = 1.0e-9
# Largest margin a load conductance is estimated for [Pa] (400 bar).
DP_MAX = 4.0e7


class EMCController(Controller):
    """Embedded Model Control in flow, margin (load sensing) and open-loop modes.

    Parameters
    ----------
    config : ControllerConfig
        ``model`` is the embedded model, ``emc`` the chosen eigenvalues; see
        :mod:`hydropump_ctrl.control.design` for the gains they give.

    Notes
    -----
    ``state()`` adds, in SI units: ``estimate`` (flow [m^3/s] or margin [Pa], by mode),
    ``flow_estimate`` (predicted pump flow now), ``flow_trajectory`` (reference generator),
    ``flow_target``, ``disturbance`` [m^3/s], ``margin_estimate`` and ``margin_trajectory``
    [Pa], ``load_conductance`` [m^3/(s Pa^(1/gamma_u))].
    """

    algorithm = 'emc'

    def _configure(self, cfg: ControllerConfig) -> None:
        self._pump = PumpModel.from_config(cfg.model)
        self._line = LineModel.from_config(cfg.model)
        self._compensated = cfg.model.load_law == 'compensated'
        self._gains = emc_gains(cfg)
        self._use_line_flow = cfg.controller.flow_signal == 'line_flow'
        if hasattr(self, '_hist') and len(self._hist) != self._gains.N + 1:
            # update_rate and t_d are read-only, so this only happens on a full reconfigure
            self._reset(self._command, {})

    # --- helpers ---------------------------------------------------------------------------

    def _model_output(self, Q: float, target: float) -> float:
        """Measured flow as the model sees it: line flow (with the zero) or pump flow."""
        return self._pump.line_flow(Q, target) if self._use_line_flow else Q

    def _clip_d(self, d: float) -> float:
        d_max = self._cfg.emc.disturbance_max
        return min(max(d, -d_max), d_max)

    def _advance_delayed(self, Qm: float, dm: float, v: float, dt: float,
                         e: float | None) -> tuple[float, float]:
        """One step of the delayed embedded model ``(Q, d)`` with the command ``v`` and the
        model error ``e`` (predictor-form noise estimator)."""
        target = v + dm
        gains = self._gains.branch(target - Qm)
        Q, sensitive = self._pump.step(Qm, target, dt)
        if e is not None:
            Q += gains.l_Q * e
            if sensitive:
                dm = self._clip_d(dm + gains.l_d * e)
        return min(max(Q, 0.0), self._pump.Q_max), dm

    def _predict(self, Qm: float, dm: float) -> float:
        """Roll the delayed model over the stored commands to the present."""
        hist, pump = self._hist, self._pump
        Q = Qm
        for j in range(self._gains.N - 2, -1, -1):
            v_j, dt_j = hist[j]
            Q = pump.step(Q, v_j + dm, dt_j)[0]
        return Q

    # --- hooks -----------------------------------------------------------------------------

    def _reset(self, current: float, meas: Mapping[str, float]) -> None:
        pump, g = self._pump, self._gains
        v = pump.flow_command(current)
        y = finite_value(meas, self._cfg.controller.flow_signal)
        Q = pump.steady_flow(current) if y is None else min(max(y, 0.0), pump.Q_max)
        # A steady state explains the measured flow with the disturbance (eq. 11 offset).
        self._dm = self._clip_d(Q - v) if 0.0 < Q < pump.Q_max else 0.0
        self._Qm = self._Qhat = self._Qr = self._Qr_next = Q
        self._Qs, self._ds = Q, self._dm
        self._hist = deque([(v, g.T)] * (g.N + 1), maxlen=g.N + 1)
        self._e = None
        self._line_corr = 0.0
        self._r = Q
        self._used_law = False
        p_l, p_u = finite_value(meas, 'line_pressure'), finite_value(meas, 'load_pressure')
        dp = (p_l - p_u) if p_l is not None and p_u is not None else self._refs['margin']
        self._dp = self._dpr = max(dp, DP_FLOOR)
        self._pu = p_u
        self._q_line = Q
        self._q_load = (Q - self._relief(p_l)) / self._fed(self._dp)
        self._lnk = math.log(max(Q, Q_FLOOR) / self._dp ** (1.0 / self._line.gamma_u))
        e = 1.0 / self._line.gamma_u
        self._lnk_min = math.log(Q_FLOOR / DP_MAX ** e)
        self._lnk_max = math.log(pump.Q_max / DP_FLOOR ** e)

    def _observe(self, dt: float, meas: Mapping[str, float]) -> None:
        g, hist, N = self._gains, self._hist, self._gains.N
        # Flow: the sample of t_k is the plant of t_k-N; compare it with the delayed model.
        y = finite_value(meas, self._cfg.controller.flow_signal)
        v_out, v_step, dt_step = hist[N][0], hist[N - 1][0], hist[N - 1][1]
        e = None if y is None else y - self._model_output(self._Qm, v_out + self._dm)
        if self.mode == 'margin':
            # The undelayed margin carries this loop: the load-conductance estimate absorbs
            # the pump model's error too (the margin depends on Q/k only), and the flow
            # sample would add nothing but its noise (0.5 % FS is 6 % of the flow at
            # xi = 0.1). The controlling model runs uncorrected; a shadow copy keeps
            # estimating the flow for a bumpless return to flow mode and for state().
            e_s = None if y is None else y - self._model_output(self._Qs, v_out + self._ds)
            self._Qs, self._ds = self._advance_delayed(self._Qs, self._ds, v_step, dt_step,
                                                       e_s)
            e = None
        self._Qm, self._dm = self._advance_delayed(self._Qm, self._dm, v_step, dt_step, e)
        if self.mode != 'margin':
            self._Qs, self._ds = self._Qm, self._dm
        self._Qhat = self._predict(self._Qm, self._dm)
        # Line: the pressure difference is not delayed; predictor-form estimator of the margin
        # and the load conductance (whose prediction is its present estimate).
        self._line_corr = 0.0
        p_l, p_u = finite_value(meas, 'line_pressure'), finite_value(meas, 'load_pressure')
        if p_u is not None:
            # The load pressure is an input of eq. 9: a step in it moves the margin at once
            # while the line pressure holds (the model state is P_l, the margin is
            # P_l - P_u). Its noise then cancels in the model error below.
            if self._pu is not None:
                self._dp = max(self._dp - (p_u - self._pu), DP_FLOOR)
            self._pu = p_u
        if p_l is not None and p_u is not None and self._compensated:
            # Compensated loads: C_l d(dp)/dt = q - q_load, the load flow a random walk;
            # predictor-form gains place the estimator's eigenvalues (design.py).
            l_p, l_q = compensated_estimator_gains(self._line.C_l, dt, g.poles['line_fast'],
                                                   g.poles['line_slow'])
            e = p_l - p_u - self._dp
            # q_load is the loads' demand; a starving load takes the fraction _fed of it.
            # The demand may exceed the pump (a saturated pump: what the loads take is then
            # all it gives, at a margin where they starve), up to what the smallest fed
            # share makes of the pump's full flow.
            self._q_load = min(max(self._q_load + l_q * e / self._fed(self._dp), 0.0),
                               self._pump.Q_max / FED_MIN)
            self._line_corr = l_p * e / self._dp
        elif p_l is not None and p_u is not None:
            gamma = self._line.gamma_u
            e_rel = (p_l - p_u - self._dp) / self._dp
            alpha = self._line.alpha(self._dp, self._q_line, dt)
            l_p, l_k = line_estimator_gains(alpha, gamma, g.poles['line_fast'],
                                            g.poles['line_slow'])
            # Bounded to the conductances a load can have (no flow at 400 bar .. full flow at
            # the floor margin): a gross start-up mismatch must not drive exp() out of range.
            self._lnk = min(max(self._lnk + l_k * e_rel, self._lnk_min), self._lnk_max)
            # The margin is propagated with the corrected conductance in _applied, which
            # already carries -gamma (1 - alpha) l_k e of the correction.
            self._line_corr = (l_p + gamma * (1.0 - alpha) * l_k) * e_rel
        self._used_law = False

    def _law(self, dt: float) -> float:
        g, pump = self._gains, self._pump
        if self.mode == 'margin':
            a = math.exp(-dt / self._cfg.emc.tau_margin_reference)
            self._dpr = self._refs['margin'] + (self._dpr - self._refs['margin']) * a
            if self._compensated:
                # The loads' demand as they take it at the margin trajectory, and the line
                # capacitance filled or drained toward it. Starving loads (below the
                # compensators' setting) are fed their demand, not what they take now:
                # every flow beyond that goes into them rather than into the margin.
                r = self._q_load * self._fed(self._dpr) + (
                    self._line.C_l * (self._dpr - self._dp) / self._cfg.emc.tau_margin_loop)
            else:
                # Cancelling the load conductance makes the margin loop the same at any
                # aperture.
                r = self._line.flow(self._dpr, math.exp(self._lnk))
            k_r = g.k_r_margin
        else:
            r = self._refs['flow']
            k_r = g.k_r
        # Compensated loads asking more than the pump gives: it saturates. The command then
        # goes to its limit (below), the spool pushed to its stop, so that the pump reaches
        # full displacement even where its pressure feedback (eq. 6) would hold it short at
        # the current of eq. 11's full flow.
        beyond = self.mode == 'margin' and self._compensated and r >= pump.Q_max
        r = min(max(r, 0.0), pump.Q_max)
        self._r = r
        # Against compensated loads a falling trajectory takes the falling-flow dynamics
        # (eq. 15): a load that shuts off must not leave the pump feeding the relief valve.
        tau = pump.tau_down if self._compensated and r < self._Qr else pump.tau
        Qr_next, v_r = trajectory_step(self._Qr, r, k_r, g.reference_limit, tau, dt)
        if Qr_next < self._Qr:
            # The trajectory is planned on the slower growing-flow dynamics; falling flow is
            # faster (eq. 15), so its feedforward comes from the falling-flow branch.
            v_r = pump.inverse(self._Qr, Qr_next, dt)
        self._Qr_next = Qr_next
        self._used_law = True
        v = v_r + g.k_x * (self._Qr - self._Qhat) - self._dm
        if beyond:
            return max(pump.current(v), self._cfg.limits.current_max)
        return pump.current(v)

    def _applied(self, u: float, desired: float, dt: float) -> None:
        pump = self._pump
        v = pump.flow_command(u)
        self._hist.appendleft((v, dt))
        target = v + self._dm
        # Line inflow over the next period, with the pilot flow of eq. 17 for falling flow.
        q_line = pump.line_flow(self._Qhat, target)
        if self._compensated:
            dp = self._line_step(q_line, dt)
        else:
            dp = self._line.step(self._dp, q_line, math.exp(self._lnk), dt)
        self._dp = max(dp + self._line_corr * self._dp, DP_FLOOR)
        self._q_line = q_line
        if self._used_law:
            self._Qr = self._Qr_next
        else:
            # Open loop or fault: the reference generator follows the plant, so that closing
            # the loop again starts from where the flow is (bumpless).
            self._Qr = pump.step(self._Qhat, target, dt)[0]
        if self.mode != 'margin' or not self._used_law:
            self._dpr = self._dp

    def _line_step(self, q_in: float, dt: float) -> float:
        """The margin after ``dt`` with the inflow ``q_in``: backward Euler of
        ``C_l d(dp)/dt = q_in - q_load fed(dp) - q_relief(dp)``. A starving load's flow
        grows steeply with the margin (an orifice near zero drop) and a small line makes the
        integrator fast: the explicit step would diverge (dt/C_l dq_out/d(dp) > 2 at a bar
        of margin on a 0.5 L line), the implicit one cannot."""
        C, dp0, p_u = self._line.C_l, self._dp, self._pu or 0.0

        def excess(x):
            q_out = self._q_load * self._fed(x) + self._relief(x + p_u)
            return x - dp0 - dt * (q_in - q_out) / C
        lo, hi = DP_FLOOR, DP_MAX
        if excess(lo) >= 0.0:
            return lo
        if excess(hi) <= 0.0:
            return hi
        while hi - lo > 1.0:  # excess grows with the margin: bisection to a pascal
            mid = 0.5 * (lo + hi)
            if excess(mid) < 0.0:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def _fed(self, dp: float) -> float:
        return fed_share(dp, self._cfg.model.dp_compensator)

    def _relief(self, p_l: float | None) -> float:
        """The relief valve's flow at line pressure ``p_l`` (its static law), in the
        compensated margin loop's model: the excess it passes is not a load to feed, so a
        load that shuts off sends the pump back to the flow the loads take at once."""
        m = self._cfg.model
        if not self._compensated or m.relief_crack <= 0.0 or p_l is None:
            return 0.0
        return static_flow(p_l, m.relief_crack, m.relief_full, m.relief_q_full)

    def _on_mode(self, old: str, new: str) -> None:
        # The trajectories start from the present estimates. Back from margin mode the flow
        # estimate of the shadow takes over: the reference generator restarts there, so the
        # command does not move (at rest v_r = Q_r and v = Q_hat - d_hat, the held command).
        if new == 'margin':
            self._dpr = self._dp
        if old == 'margin':
            self._Qm, self._dm = self._Qs, self._ds
            self._Qhat = self._predict(self._Qm, self._dm)
            self._Qr = self._Qr_next = self._Qhat

    def _flow_estimate(self) -> float:
        """Best present flow estimate: the shadow's in margin mode."""
        if self.mode == 'margin':
            return self._predict(self._Qs, self._ds)
        return self._Qhat

    def _estimate(self, mode: str) -> float | None:
        return self._flow_estimate() if mode == 'flow' else self._dp

    def _state(self) -> dict:
        q = self._flow_estimate()
        return {
            'estimate': self._dp if self.mode == 'margin' else q,
            'flow_estimate': q, 'flow_trajectory': self._Qr, 'flow_target': self._r,
            'disturbance': self._ds, 'margin_estimate': self._dp,
            'margin_trajectory': self._dpr, 'load_conductance': math.exp(self._lnk),
            'load_flow_estimate': self._q_load,
        }
