#include "benchmark/layouts.hpp"

#include <fmt/format.h>

namespace pp5::harness {

std::string Layout::name() const {
  std::string n =
      fmt::format("g{}p{}_{}_{}_t{}", gps, pps, partition, owner == "contiguous" ? "contig" : "inter", tileSize);
  if (paceFps > 0.0) n += fmt::format("_paced{:g}", paceFps);
  if (tcp) n += "_tcp";
  if (repeat > 1) n += fmt::format("_r{}", repeat);
  return n;
}

Layout makeLayout(int g, int p, const std::string& part, const std::string& owner, int tile, double pace) {
  Layout l;
  l.gps = g;
  l.pps = p;
  l.partition = part;
  l.owner = owner;
  l.tileSize = tile;
  l.paceFps = pace;
  l.target = g == 2 && p == 1 && owner == "contiguous" && tile == 128;
  return l;
}

// The target first, then G and P sweeps with odd counts, tile ownership and
// tile size. The paced target, which the figures judge, runs three
// times (start, middle, end), since what else the machine runs moves it.
std::vector<Layout> layouts(bool quick) {
  std::vector<Layout> v;
  auto paced = [&](int repeat) {
    for (const char* part : {"slab", "tile"}) {
      v.push_back(makeLayout(2, 1, part, "contiguous", 128, 30.0));
      v.back().repeat = repeat;
    }
  };
  for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(2, 1, part));
  paced(1);
  if (quick) return {v[0], v[3]};
  for (int g : {1, 3, 5})
    for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(g, 1, part));
  paced(2);
  for (int p : {2, 3})
    for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(2, p, part));
  for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(2, 2, part, "interleaved"));
  v.push_back(makeLayout(3, 1, "tile", "interleaved"));
  for (int tile : {64, 256})
    for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(2, 2, part, "contiguous", tile));
  paced(3);
  return v;
}

}  // namespace pp5::harness
