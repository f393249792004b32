#pragma once
// The partitioning benchmark's layouts: how many GPs and PPs, which
// partitioning, tile ownership and tile size, paced or not.
#include <string>
#include <vector>

namespace pp5::harness {

struct Layout {
  int gps = 2, pps = 1;
  std::string partition = "slab";    // parallel.gp_partition
  std::string owner = "contiguous";  // parallel.tile_owner
  int tileSize = 128;                // parallel.tile_size
  double paceFps = 0.0;              // run.pace_fps
  bool target = false;               // the 1 host + 2 GP + 1 PP layout
  int repeat = 1;                    // the paced target runs at the start, middle and end
  bool tcp = false;                  // Open MPI's TCP transport (--mca pml ob1 --mca btl tcp,self), a cluster's stand-in

  int ranks() const { return 1 + gps + pps; }
  // g<G>p<P>_<partition>_<contig|inter>_t<tile>[_paced<fps>][_tcp][_r<repeat>]
  std::string name() const;
};

Layout makeLayout(int g, int p, const std::string& part, const std::string& owner = "contiguous", int tile = 128,
                  double pace = 0.0);
// The target first, then G and P sweeps with odd counts, tile ownership and
// tile size; the paced target three times (start, middle, end). quick: two
// layouts, a smoke test.
std::vector<Layout> layouts(bool quick);

}  // namespace pp5::harness
