"""The STEP export's helper process (workers.py starts it): `python -m sweepedit.io.step
REPLIES_FD`."""

import sys

from sweepedit.io.step.workers import serve_helper

if __name__ == "__main__":
    serve_helper(int(sys.argv[1]))
