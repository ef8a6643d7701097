"""The model's form, as both front ends show it: noise entering ``fx``/``hx``, and the outlier gate.

:class:`ModelForm` is a small base class of :class:`squkf.SquareRootUKF` and
:class:`squkf.Fleet`: they set ``_fx_noise`` and ``_hx_noise`` (0 for additive
noise, :func:`squkf.noise.check_noise_dim`) at construction, and the gate
through its property (checked by :func:`squkf.gating.as_gate`).
"""

from __future__ import annotations

from ..gating import Gate, as_gate

__all__ = ["ModelForm"]


class ModelForm:
    """``fx_noise``, ``hx_noise`` (read-only) and ``gate`` (checked when assigned)."""

    _fx_noise: int
    _hx_noise: int
    _gate: Gate | None

    @property
    def fx_noise(self) -> int | None:
        """Dimension of the noise ``fx`` takes as its second argument (None: additive noise)."""
        return self._fx_noise or None

    @property
    def hx_noise(self) -> int | None:
        """Dimension of the noise ``hx`` takes as its second argument (None: additive noise)."""
        return self._hx_noise or None

    @property
    def gate(self) -> Gate | None:
        """The outlier gate (None: every measurement is used); assign a probability or a Gate."""
        return self._gate

    @gate.setter
    def gate(self, value) -> None:
        self._gate = as_gate(value)
