#pragma once
// What a run writes besides the rendered images: orthogonal slices (MPR)
// through the reconstructed volume, and the per-frame statistics file.
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "core/volume_io.hpp"

namespace pp5::host {

// Three orthogonal slices through voxel `centre` of a grey-level volume
// (values clamped to 0..255), as PNGs: `<stem>_axial.png` (the xy plane, +y
// up), `<stem>_coronal.png` (xz, +z up) and `<stem>_sagittal.png` (yz, +z
// up). Voxels are assumed square in each slice; other spacings are resampled
// to the finest one by nearest neighbour, so the slices keep their true
// proportions. Returns the paths written.
std::vector<std::string> writeMpr(const Volume& v, const Index3& centre, const std::string& stem);

// One CSV row per frame (header first), flushed as it goes, so a long run can
// be watched and an interrupted one keeps its rows.
class StatsCsv {
public:
  explicit StatsCsv(const std::string& path, const std::vector<std::string>& columns);
  ~StatsCsv();
  StatsCsv(const StatsCsv&) = delete;
  StatsCsv& operator=(const StatsCsv&) = delete;
  void row(const std::vector<double>& values);  // as many values as columns

private:
  std::FILE* f_ = nullptr;
  std::size_t columns_ = 0;
  std::string path_;
};

}  // namespace pp5::host
