#!/bin/sh
# Builds the CGAL reference program of `cargo bench --bench alpha` into target/cgal/.
# Needs Debian's libcgal-dev, libgmp-dev and libmpfr-dev (apt-get install them); CGAL is
# never a dependency of toporec, only the benchmark's yardstick.
set -eu
cd "$(dirname "$0")/.."
mkdir -p target/cgal
g++ -O3 -march=native -DNDEBUG -std=c++17 benches/cgal/delaunay_3.cpp -o target/cgal/delaunay_3 -lgmp -lmpfr
echo "built target/cgal/delaunay_3"
