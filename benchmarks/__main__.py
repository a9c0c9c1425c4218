import sys

from benchmarks import main

main(sys.argv[1:])
