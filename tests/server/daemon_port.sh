# Kept for tests that source it by this name; the fixture is daemon.sh.
source "$(dirname "${BASH_SOURCE[0]}")/daemon.sh"
