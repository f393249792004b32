// `pp5echo info FILE`: describes a PLUS sequence or a volume as JSON.
// Volumes: from the header alone, so a volume of any size is described
// without loading it. Sequences: streamed frame by frame, which also checks
// that every frame's data is there and decodes.
#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <string>

#include "app/commands.hpp"
#include "formats/recording_journal.hpp"
#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"

namespace pp5::app {

namespace {

using Json = nlohmann::ordered_json;

const char* formatName(SequenceFormat f) { return f == SequenceFormat::MetaIO ? "metaio" : "nrrd"; }

// The readers choose the format by extension, so this names the one used.
const char* volumeFormatName(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  return ext == ".nrrd" || ext == ".nhdr" || ext == ".NRRD" || ext == ".NHDR" ? "nrrd" : "metaio";
}

Json vec3(const Vec3& v) { return Json::array({v.x, v.y, v.z}); }

Json describeVolume(const std::string& path) {
  const VolumeHeader h = checkVolumeFile(path);
  Json j;
  j["file"] = path;
  j["kind"] = "volume";
  j["format"] = volumeFormatName(path);
  j["dims"] = Json::array({h.grid.dims.x, h.grid.dims.y, h.grid.dims.z});
  j["spacing"] = vec3(h.grid.spacing);
  j["origin"] = vec3(h.grid.origin);
  j["scalar_type"] = scalarName(h.type);
  j["channels"] = h.channels;
  j["compressed"] = h.compressed;
  j["memory_bytes"] = h.grid.memoryBytes(static_cast<std::uint64_t>(scalarBytes(h.type) * h.channels));
  return j;
}

struct TransformCount {
  std::string name;
  std::uint64_t frames = 0;
  std::uint64_t valid = 0;
};

Json describeSequence(const std::string& path) {
  auto reader = SequenceReader::open(path);
  std::vector<TransformCount> transforms;  // in order of first appearance
  std::uint64_t validImages = 0;
  Json time = nullptr;
  Frame f;
  while (reader->next(f)) {
    if (f.imageValid) ++validImages;
    if (time.is_null()) time = Json{{"first", f.timestamp}};
    time["last"] = f.timestamp;
    for (const auto& t : f.transforms) {
      auto it = std::find_if(transforms.begin(), transforms.end(), [&](const auto& c) { return c.name == t.name; });
      if (it == transforms.end()) it = transforms.insert(transforms.end(), TransformCount{t.name});
      ++it->frames;
      if (t.valid) ++it->valid;
    }
  }
  if (!time.is_null()) time["duration"] = time["last"].get<double>() - time["first"].get<double>();

  const SequenceInfo& info = reader->info();
  Json j;
  j["file"] = path;
  j["kind"] = "sequence";
  j["format"] = formatName(info.format);
  j["frame_count"] = info.frameCount;
  j["image_size"] = Json::array({info.width, info.height});
  j["pixel_type"] = info.pixelType == PixelType::U8 ? "uint8" : "uint16";
  j["orientation"] = info.orientation.empty() ? "MF" : info.orientation;
  j["compressed"] = info.compressed;
  j["fields"] = Json::object();
  for (const auto& [key, value] : info.fields) j["fields"][key] = value;
  j["valid_image_frames"] = validImages;
  j["transforms"] = Json::object();
  for (const auto& t : transforms) j["transforms"][t.name] = Json{{"frames", t.frames}, {"valid_frames", t.valid}};
  j["time"] = time;
  if (std::filesystem::path(path).extension() == ".journal") {  // a recording that was cut off
    JournalContents c;
    openJournal(path, &c);
    j["journal"] = Json{{"sequence", c.sequencePath}, {"complete_frames", c.frames}, {"kept_bytes", c.keptBytes},
                        {"file_bytes", c.fileBytes}, {"cut", c.cut.empty() ? Json(nullptr) : Json(c.cut)},
                        {"damaged", c.damaged}, {"damaged_bytes", c.damagedBytes},
                        {"restore", "pp5echo restore " + path}};
  }
  return j;
}

}  // namespace

void addInfoCommand(CLI::App& app, int& exitCode) {
  auto file = std::make_shared<std::string>();
  auto* cmd = app.add_subcommand("info", "Describe a PLUS sequence (.igs.mha, .igs.nrrd, ...) or a volume as JSON");
  // Not CLI11's ExistingFile check: a missing file should get the same
  // one-line error as any other bad input.
  cmd->add_option("FILE", *file, "Sequence or volume (.mha, .mhd, .nrrd), or a cut-off recording's .journal")
      ->required();
  cmd->callback([file, &exitCode] {
    logToStderr();
    const bool sequence = probeImageFile(*file) == ImageFileKind::Sequence;
    const Json j = sequence ? describeSequence(*file) : describeVolume(*file);
    std::string text;
    try {
      text = j.dump(2);
    } catch (const Json::type_error&) {
      // JSON is UTF-8: a header written in another encoding is shown with
      // U+FFFD where its bytes are not UTF-8, and said so, naming the file.
      text = j.dump(2, ' ', false, Json::error_handler_t::replace);
      spdlog::warn("{}: the header holds bytes that are not UTF-8; they are shown as U+FFFD", *file);
    }
    std::cout << text << '\n';
    exitCode = 0;
  });
}

}  // namespace pp5::app
