"""nlpcal: three-axis magnetometer calibration as CasADi/IPOPT nonlinear programs.

    result = nlpcal.calibrate(samples, method="staged", reference_field=None)
    corrected = result.apply(samples)
"""

__version__ = "0.1.0"

from .calibration import CalibrationResult, calibrate  # noqa: E402
from .models.zhou2010 import Zhou2010Parameters  # noqa: E402

__all__ = ["calibrate", "CalibrationResult", "Zhou2010Parameters", "__version__"]
