# agents/sweep.py moved to the a3c_tools package: the tools live apart from the algorithms.
import shlex
import sys

new = shlex.join(["python", "-m", "a3c_tools.sweep", *sys.argv[1:]])
print(f"error: agents/sweep.py moved; run: {new}", file=sys.stderr)
sys.exit(2)
