"""The filter's settings as its classes defaulted to before they were built from the registry:
no local model error, per-distance or heading states, the storm walking per element, an AHRS of
its own, a quiet walk of 0.0002 deg and 0.2 nT per sqrt(h). The unit tests below were written
against these; the companion has always flown the registry's (FUS_*), which now are the classes'
defaults too."""
from __future__ import annotations

from companion.nav.disturbance import ELEMENT_WALK
from companion.nav.ins_error import AttitudeSource
from companion.nav.navfilter import BiasSpec, FilterSettings

BARE_BIAS = dict(q_deg_rth=0.0002, q_nt_rth=0.2, local_deg=0.0, local_nt=0.0, qd_deg_rkm=0.0, qd_nt_rkm=0.0,
                 heading_deg=0.0, heading_nt=0.0, qa_mode=ELEMENT_WALK)


def bare_bias(**changes) -> BiasSpec:
    """:class:`BiasSpec` at the former defaults, with ``changes``."""
    return BiasSpec(**{**BARE_BIAS, **changes})


def bare_filter(**changes) -> FilterSettings:
    """:class:`FilterSettings` at the former defaults (the bias too), with ``changes``."""
    return FilterSettings(**{"bias": bare_bias(), "attitude_from_ins": AttitudeSource.NONE, **changes})
