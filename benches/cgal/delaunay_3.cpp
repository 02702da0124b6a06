// CGAL's Delaunay_triangulation_3 alone, the reference the alpha benchmark compares
// toporec's engine against (`cargo bench --bench alpha`). Never a dependency of toporec.
//
// Reads CSV paths (an `x,y,z` header, then one point a line) from stdin, one a line; for
// each, triangulates its points once to warm up, then once timed, and prints
// `milliseconds,finite cells` on stdout. The points are parsed before the clock starts and
// inserted as a range (CGAL spatially sorts them, as toporec does), with the EPICK kernel.
//
// Build: `scripts/build_cgal_reference.sh` (needs Debian's libcgal-dev, libgmp-dev, libmpfr-dev).

#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Delaunay = CGAL::Delaunay_triangulation_3<Kernel>;
using Point = Kernel::Point_3;

static bool read_csv(const std::string& path, std::vector<Point>& out) {
  std::ifstream in(path);
  if (!in) return false;
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    double x, y, z;
    char c1, c2;
    std::istringstream s(line);
    if (!(s >> x >> c1 >> y >> c2 >> z)) return false;
    out.emplace_back(x, y, z);
  }
  return true;
}

int main() {
  std::string path;
  while (std::getline(std::cin, path)) {
    std::vector<Point> points;
    if (!read_csv(path, points)) {
      std::printf("error,%s\n", path.c_str());
      std::fflush(stdout);
      continue;
    }
    std::size_t cells = 0;
    double ms = 0.0;
    for (int run = 0; run < 2; ++run) {
      auto t0 = std::chrono::steady_clock::now();
      Delaunay dt(points.begin(), points.end());
      auto t1 = std::chrono::steady_clock::now();
      cells = dt.number_of_finite_cells();
      ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    }
    std::printf("%.4f,%zu\n", ms, cells);
    std::fflush(stdout);
  }
  return 0;
}
