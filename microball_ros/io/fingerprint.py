"""The platform fingerprint: what decides the last bits of every float this process computes.

Floats depend on the CPU through numpy's SIMD dispatch (AVX-512 or AVX2 kernels, chosen at run
time and narrowed by ``NPY_DISABLE_CPU_FEATURES``) and OpenBLAS's kernel (chosen by CPU, or by
``OPENBLAS_CORETYPE``), and on the versions of the stack. ``fingerprint()`` records all of them,
plus the CPU model, Python and this package's version, as a flat mapping of strings that goes
into every bag's ``custom_data``; ``numeric_key()`` is the part that must match for two runs to
agree byte for byte (docs/design.md section 4, determinism contract (a)).
"""

import hashlib
import json
import os
import platform
import sys

import numpy as np
import scipy

from microball_ros import __version__

# The key under which a bag's metadata.yaml custom_data carries the fingerprint (a JSON string).
CUSTOM_DATA_KEY = 'microball.platform'

# Entries that decide the numbers; the rest (CPU model, machine name) only explain them.
NUMERIC_FIELDS = ('numpy', 'scipy', 'numpy_simd', 'blas', 'python', 'machine', 'microball_ros')


def _numpy_simd():
    """Return the SIMD targets numpy dispatches to in this process, e.g. 'X86_V2 X86_V3 X86_V4'."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy < 2
        from numpy.core import _multiarray_umath as umath
    features = umath.__cpu_features__
    used = [name for name in umath.__cpu_dispatch__ if features.get(name)]
    return ' '.join([*umath.__cpu_baseline__, *used])


def _blas():
    """Return numpy's and scipy's BLAS as 'name version architecture', joined by '; '.

    Only the libraries our numbers go through: OpenCV brings an OpenBLAS of its own, and
    whether a process imported cv2 must not change the fingerprint.
    """
    import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, which threadpoolctl then sees)
    from threadpoolctl import threadpool_info

    roots = {os.path.dirname(os.path.dirname(module.__file__)) for module in (np, scipy)}
    ours = tuple(os.path.join(root, name) + os.sep for root in roots
                 for name in ('numpy', 'numpy.libs', 'scipy', 'scipy.libs'))
    libraries = sorted({
        f"{info.get('internal_api')} {info.get('version')} {info.get('architecture')}"
        for info in threadpool_info()
        if info.get('user_api') == 'blas' and info.get('filepath', '').startswith(ours)})
    return '; '.join(libraries) or 'none'


def _cpu_model():
    """Return the CPU model name as the kernel reports it, else what platform knows."""
    try:
        with open('/proc/cpuinfo') as handle:
            for line in handle:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown'


def fingerprint():
    """Return this process's platform fingerprint: a dict of short strings."""
    info = {
        'numpy': np.__version__,
        'scipy': scipy.__version__,
        'numpy_simd': _numpy_simd(),
        'blas': _blas(),
        'python': platform.python_version(),
        'machine': platform.machine(),
        'microball_ros': __version__,
        'cpu': _cpu_model(),
        'system': f'{platform.system()} {platform.release()}',
    }
    info['key'] = numeric_key(info)
    return info


def numeric_key(info):
    """Return a short hash of the fields of a fingerprint that decide the numbers."""
    text = json.dumps({name: info.get(name) for name in NUMERIC_FIELDS}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def to_custom_data(info=None):
    """Return the fingerprint as one custom_data entry {CUSTOM_DATA_KEY: JSON text}."""
    return {CUSTOM_DATA_KEY: json.dumps(info or fingerprint(), sort_keys=True)}


def from_custom_data(custom_data):
    """Return the fingerprint a bag's custom_data carries, or None if it has none."""
    text = (custom_data or {}).get(CUSTOM_DATA_KEY)
    if not text:
        return None
    try:
        info = json.loads(text)
    except ValueError:
        return None
    return info if isinstance(info, dict) else None


def differences(recorded, current):
    """Return 'field: recorded -> current' for each numeric field that differs (a list)."""
    if recorded is None:
        return ['the bag carries no platform fingerprint']
    return [f'{name}: {recorded.get(name)} -> {current.get(name)}'
            for name in (*NUMERIC_FIELDS, 'cpu') if recorded.get(name) != current.get(name)]


if __name__ == '__main__':  # pragma: no cover - a quick look by hand
    json.dump(fingerprint(), sys.stdout, indent=1)
    print()
