"""The platform fingerprint: what decides the last bits of the numbers, stable within a process."""

import subprocess
import sys

from microball_ros.io import fingerprint


def test_fingerprint_names_the_stack_and_its_key_is_a_hash_of_the_numeric_fields():
    info = fingerprint.fingerprint()
    import numpy as np
    import scipy

    assert info['numpy'] == np.__version__ and info['scipy'] == scipy.__version__
    assert info['numpy_simd'].split()[0].startswith(('X86', 'SSE', 'NEON', 'VSX', 'ASIMD'))
    assert 'openblas' in info['blas']
    assert info['key'] == fingerprint.numeric_key(info)
    changed = dict(info, numpy_simd='X86_V2 FAKE_SIMD')
    assert fingerprint.numeric_key(changed) != info['key']
    assert fingerprint.numeric_key(dict(info, cpu='another model')) == info['key']


def test_importing_opencv_does_not_change_the_fingerprint():
    code = ('from microball_ros.io import fingerprint as f\n'
            'a = f.fingerprint()\n'
            'import cv2, numpy as np\n'
            'cv2.resize(np.ones((4, 4)), (2, 2))\n'
            "print(a['key'] == f.fingerprint()['key'])")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            check=True)
    assert result.stdout.strip() == 'True'


def test_custom_data_round_trip_and_differences():
    info = fingerprint.fingerprint()
    custom = fingerprint.to_custom_data(info)
    assert list(custom) == [fingerprint.CUSTOM_DATA_KEY]
    assert fingerprint.from_custom_data(custom) == info
    assert fingerprint.from_custom_data({}) is None
    assert fingerprint.from_custom_data({fingerprint.CUSTOM_DATA_KEY: 'not json'}) is None
    other = dict(info, numpy_simd='X86_V2 FAKE_SIMD', cpu='Intel Xeon')
    assert fingerprint.differences(info, other) == [
        f"numpy_simd: {info['numpy_simd']} -> X86_V2 FAKE_SIMD",
        f"cpu: {info['cpu']} -> Intel Xeon"]
    assert fingerprint.differences(None, info) == ['the bag carries no platform fingerprint']
