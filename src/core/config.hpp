#pragma once
// TOML configuration with a schema. Every option is registered once, with its
// type, default, range and one line of documentation; the same registry
// parses files, rejects unknown keys, wrong types and out-of-range values
// (InputError "FILE:LINE: ..."), and generates docs/configuration.md
// (`pp5echo config --markdown`), so the docs cannot drift from the code.
//
// Each module registers its own section into a ConfigSchema that binds keys to
// fields of that module's settings struct (e.g. sim::registerOptions).
#include <cstdint>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include <glm/glm.hpp>

namespace toml {
inline namespace v3 {
class node;
}
}  // namespace toml

namespace pp5 {

class ConfigSchema {
public:
  // Describes one section ("[sim]") for the docs.
  void section(const std::string& name, const std::string& doc);

  void option(const std::string& key, bool* field, bool def, const std::string& doc);
  void option(const std::string& key, int* field, int def, int lo, int hi, const std::string& doc);
  void option(const std::string& key, std::uint64_t* field, std::uint64_t def, std::uint64_t lo, std::uint64_t hi,
              const std::string& doc);
  void option(const std::string& key, double* field, double def, double lo, double hi, const std::string& doc);
  void option(const std::string& key, std::string* field, const std::string& def, const std::string& doc);
  // A string restricted to `choices`.
  void choice(const std::string& key, std::string* field, const std::string& def,
              const std::vector<std::string>& choices, const std::string& doc);
  // A string restricted to `choices`, stored as its index (enum options:
  // core/enum_names.hpp's enumOption).
  void choiceIndex(const std::string& key, const std::vector<std::string>& choices, std::size_t def,
                   std::function<void(std::size_t)> set, std::function<std::size_t()> get, const std::string& doc);
  // Fixed-length number arrays, each element within [lo, hi].
  void option(const std::string& key, glm::dvec3* field, glm::dvec3 def, double lo, double hi, const std::string& doc);
  void option(const std::string& key, glm::dvec2* field, glm::dvec2 def, double lo, double hi, const std::string& doc);
  void option(const std::string& key, glm::ivec3* field, glm::ivec3 def, int lo, int hi, const std::string& doc);
  void option(const std::string& key, glm::ivec2* field, glm::ivec2 def, int lo, int hi, const std::string& doc);
  // A non-empty list of points, each an array of `width` numbers (2..4) within
  // [lo, hi], stored in the first `width` components: [[0, 0.0], [40, 0.2], ...].
  // With `ascending`, the points' first components must increase strictly.
  void option(const std::string& key, std::vector<glm::dvec4>* field, const std::vector<glm::dvec4>& def, int width,
              double lo, double hi, bool ascending, const std::string& doc);
  // A non-empty list of distinct strings, each one of `choices`.
  void choices(const std::string& key, std::vector<std::string>* field, const std::vector<std::string>& def,
               const std::vector<std::string>& choices, const std::string& doc);

  // A non-empty list of distinct choices, stored as their indices (enum
  // lists: core/enum_names.hpp's enumListOption).
  void choicesIndex(const std::string& key, const std::vector<std::string>& choices, std::vector<std::size_t> def,
                    std::function<void(const std::vector<std::size_t>&)> set,
                    std::function<std::vector<std::size_t>()> get, const std::string& doc);

  // A list of strings, possibly empty: ["40 render.azimuth_deg = 30", ...].
  void option(const std::string& key, std::vector<std::string>* field, const std::vector<std::string>& def,
              const std::string& doc);

  // Sets every field to its default (and forgets which keys were assigned).
  void applyDefaults() const;
  // Whether a file or an override assigned `key` since the last applyDefaults
  // (a value derived at run time must not replace one the user gave).
  bool assigned(const std::string& key) const { return assigned_.count(key) != 0; }
  const std::set<std::string>& assignedKeys() const { return assigned_; }
  // Parses a TOML file over the current values. Unknown keys, wrong types and
  // out-of-range values throw InputError naming the file, the key and the line.
  void loadFile(const std::string& path) const;
  void loadString(const std::string& text, const std::string& sourceName) const;
  // One `key=value` override from the command line (value in TOML syntax).
  void set(const std::string& assignment) const;

  // docs/configuration.md content.
  std::string markdown() const;
  // The current values as a TOML document (what a run used; written beside outputs).
  std::string toToml() const;

  struct Entry {
    std::string key;      // "sim.seed"
    std::string type;     // for the docs: "integer", "float", "string", "bool", "[float, float, float]", ...
    std::string def;      // default, as TOML text
    std::string range;    // "0 .. 100", "one of: a, b", or ""
    std::string doc;
    std::function<void()> reset;
    // Reads the node into the field; returns an error message (without location) or "".
    std::function<std::string(const toml::node&)> assign;
    std::function<std::string()> current;  // current value as TOML text
  };
  const std::vector<Entry>& entries() const { return entries_; }

private:
  struct Section {
    std::string name, doc;
  };
  std::vector<Section> sections_;
  std::vector<Entry> entries_;
  mutable std::set<std::string> assigned_;
  void add(Entry e);
};

}  // namespace pp5
