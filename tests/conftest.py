import os
import sys

# The statistics helpers live beside the tests.
sys.path.insert(0, os.path.dirname(__file__))
