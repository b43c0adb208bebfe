"""The gap fits' recursive filter: the product's one filter,
:func:`nmsid.protocols.lti_kernels.lfilter` (``scipy.signal``'s compiled ``lfilter`` kernel
loaded without ``import scipy.signal``), re-exported here for callers of the former module.
"""

from __future__ import annotations

from nmsid.protocols.lti_kernels import lfilter

__all__ = ["lfilter"]
