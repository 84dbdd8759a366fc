#!/usr/bin/env bash
# CI's slow-tests step: the tests `cargo test` leaves out, marked
# #[ignore = "slow: ..."] (1 M-triangle inputs). Each promise they check
# is also checked on a smaller input by `cargo test --locked`; these repeat
# it at the size it was first found at. Arguments go to the test harness
# (e.g. a name filter: tools/slow-tests.sh reliability). The readers'
# decode-speed measurements (src/input/, also #[ignore]d) are skipped: they
# are benchmarks, run in release by hand (docs/ply-and-soup.md).
set -euo pipefail
cd "$(dirname "$0")/.."
exec cargo test --locked -- --ignored --skip input:: "$@"
