# agents/plot_evaluations.py moved to the a3c_tools package, apart from the algorithms.
import shlex
import sys

new = shlex.join(["python", "-m", "a3c_tools.plot_evaluations", *sys.argv[1:]])
print(f"error: agents/plot_evaluations.py moved; run: {new}", file=sys.stderr)
sys.exit(2)
