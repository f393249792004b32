#include "host/outputs.hpp"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/error.hpp"
#include "core/image_io.hpp"

namespace pp5::host {

namespace {

// Slice of `v` across axes (a, b) at coordinate `at` of the third axis c:
// image x follows a, image y follows b downwards from its top (so +b is up).
void writeSlice(const Volume& v, int a, int b, int c, std::int64_t at, const std::string& path) {
  const Grid& g = v.grid;
  const double pitch = std::min(g.spacing[a], g.spacing[b]);
  const int w = static_cast<int>(std::max<std::int64_t>(1, std::llround(g.dims[a] * g.spacing[a] / pitch)));
  const int h = static_cast<int>(std::max<std::int64_t>(1, std::llround(g.dims[b] * g.spacing[b] / pitch)));
  std::vector<std::uint8_t> px(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      Index3 i(0);
      i[a] = std::min<std::int64_t>(g.dims[a] - 1, static_cast<std::int64_t>((x + 0.5) * pitch / g.spacing[a]));
      i[b] = std::min<std::int64_t>(g.dims[b] - 1,
                                    static_cast<std::int64_t>((h - 1 - y + 0.5) * pitch / g.spacing[b]));
      i[c] = at;
      const double val = v.value(g.linear(i.x, i.y, i.z));
      px[static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x)] =
          static_cast<std::uint8_t>(std::lround(std::clamp(val, 0.0, 255.0)));
    }
  writeGrayPng(path, w, h, px.data());
}

}  // namespace

std::vector<std::string> writeMpr(const Volume& v, const Index3& centre, const std::string& stem) {
  const Grid& g = v.grid;
  PP5_CHECK(centre.x >= 0 && centre.y >= 0 && centre.z >= 0 && centre.x < g.dims.x && centre.y < g.dims.y &&
            centre.z < g.dims.z);
  const std::vector<std::string> paths = {stem + "_axial.png", stem + "_coronal.png", stem + "_sagittal.png"};
  writeSlice(v, 0, 1, 2, centre.z, paths[0]);
  writeSlice(v, 0, 2, 1, centre.y, paths[1]);
  writeSlice(v, 1, 2, 0, centre.x, paths[2]);
  return paths;
}

StatsCsv::StatsCsv(const std::string& path, const std::vector<std::string>& columns)
    : columns_(columns.size()), path_(path) {
  f_ = std::fopen(path.c_str(), "w");
  if (!f_) inputError(path, "cannot write the statistics file");
  for (std::size_t i = 0; i < columns.size(); ++i) std::fprintf(f_, "%s%s", i ? "," : "", columns[i].c_str());
  std::fprintf(f_, "\n");
  std::fflush(f_);
}

StatsCsv::~StatsCsv() {
  if (f_) std::fclose(f_);
}

void StatsCsv::row(const std::vector<double>& values) {
  PP5_CHECK_EQ(values.size(), columns_);
  std::string line;
  for (std::size_t i = 0; i < values.size(); ++i) line += (i ? "," : "") + fmt::format("{:.6g}", values[i]);
  line += "\n";
  if (std::fputs(line.c_str(), f_) < 0 || std::fflush(f_) != 0) inputError(path_, "cannot write a statistics row");
}

}  // namespace pp5::host
