"""Start-up hook of the sanitizer build: ./dev sanitize installs this file into .venv-sanitize
as _csb_sanitizer_hook.py, with a .pth file that imports it, so that every Python process of
that environment (pytest, the meshio reader's ``python -I``, the CLI and scripts the tests start)
runs it before anything loads csb.

g++'s AddressSanitizer and UndefinedBehaviorSanitizer runtimes are two libraries, libasan and
libubsan, that both export __sanitizer_set_report_path. libasan is preloaded, so it takes
libubsan's own call: UBSAN_OPTIONS' log_path sets ASan's log file, and UBSan keeps printing to
stderr, where a test's capture or a child's redirection hides it. Calling libubsan's copy
through its own handle gives UBSan's reports their log file (CSB_UBSAN_LOG; forked children
write to their own, by process id).
"""

import os

_log = os.environ.get("CSB_UBSAN_LOG")
if _log:
    import ctypes

    ctypes.CDLL(os.environ["CSB_UBSAN_RUNTIME"]).__sanitizer_set_report_path(_log.encode())
