"""The paper's two feedforward controllers (Section IV), here for their historical names.

* :class:`InversePIFeedforward` - the command is the inverse P-I model, eqs. (12)-(15), applied
  to the desired displacement: ``u = P^-1[x_d]`` (:mod:`piezohyst.models.pi`).
* :class:`BoucWenFeedforward` - the hysteresis-estimate controller of eq. (10),
  ``u_c = (x_d + h_hat) / d1`` (:mod:`piezohyst.models.bouc_wen_inverse`).

Every model kind has its own compensator, ``model.compensator()``; these two are the P-I's and
the Bouc-Wen model's. Both take the desired displacement in µm and give volts; both stream
(``step(x_d_k)``) and run on whole signals (``command(x_d)``) through the same compiled kernel.
"""

from __future__ import annotations

from ..models.bouc_wen_inverse import BoucWenFeedforward, bw_ff_run, bw_ff_step
from ..models.pi import InversePIFeedforward

__all__ = ["BoucWenFeedforward", "InversePIFeedforward", "bw_ff_run", "bw_ff_step"]
