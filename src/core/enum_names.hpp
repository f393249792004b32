#pragma once
// Every option with a fixed set of values is an enum with its names written
// once, as a specialisation of EnumNames next to the enum:
//
//   template <> struct EnumNames<SlabSplit> {
//     static constexpr std::string_view key = "parallel.slab_split";
//     static constexpr std::array<std::pair<SlabSplit, std::string_view>, 2> names{{
//         {SlabSplit::Longest, "longest"}, {SlabSplit::Grid3d, "3d"}}};
//   };
//
// enumName, enumFromName and the configuration schema's enum options
// (enumOption) all read that one table, so a name cannot be spelled two ways.
#include <array>
#include <cstddef>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/config.hpp"
#include "core/error.hpp"

namespace pp5 {

template <typename E>
struct EnumNames;  // specialised next to each enum

// The name of e ("?" for a value outside the table, which only a corrupted
// value can be).
template <typename E>
std::string_view enumName(E e) {
  for (const auto& [v, n] : EnumNames<E>::names)
    if (v == e) return n;
  return "?";
}

// Every name, in the table's order.
template <typename E>
std::vector<std::string> enumNameList() {
  std::vector<std::string> out;
  for (const auto& p : EnumNames<E>::names) out.emplace_back(p.second);
  return out;
}

// The value named `name`; InputError "KEY = "name" is not one of a, b, c"
// (KEY: `what`, or the table's configuration key) otherwise.
template <typename E>
E enumFromName(std::string_view name, std::string_view what = EnumNames<E>::key) {
  for (const auto& [v, n] : EnumNames<E>::names)
    if (n == name) return v;
  std::string list;
  for (const auto& p : EnumNames<E>::names) list += (list.empty() ? "" : ", ") + std::string(p.second);
  throw InputError(std::string(what) + " = \"" + std::string(name) + "\" is not one of " + list);
}

// e itself when it is one of the table's values; InputError otherwise (an
// enum set in code to a value no configuration file could give).
template <typename E>
E checkedEnum(E e) {
  return enumFromName<E>(enumName(e));
}

// Registers an enum field as a string option restricted to its names.
template <typename E>
void enumOption(ConfigSchema& schema, const std::string& key, E* field, E def, const std::string& doc) {
  std::vector<std::string> names = enumNameList<E>();
  std::size_t defIndex = names.size();
  for (std::size_t i = 0; i < EnumNames<E>::names.size(); ++i)
    if (EnumNames<E>::names[i].first == def) defIndex = i;
  PP5_CHECK_LT(defIndex, names.size());
  schema.choiceIndex(
      key, names, defIndex, [field](std::size_t i) { *field = EnumNames<E>::names[i].first; },
      [field] {
        for (std::size_t i = 0; i < EnumNames<E>::names.size(); ++i)
          if (EnumNames<E>::names[i].first == *field) return i;
        return EnumNames<E>::names.size();  // written as "?": no file could have given it
      },
      doc);
}

// Registers a list of distinct enum values as a list-of-strings option.
template <typename E>
void enumListOption(ConfigSchema& schema, const std::string& key, std::vector<E>* field, const std::vector<E>& def,
                    const std::string& doc) {
  auto indexOf = [](E e) {
    for (std::size_t i = 0; i < EnumNames<E>::names.size(); ++i)
      if (EnumNames<E>::names[i].first == e) return i;
    return EnumNames<E>::names.size();
  };
  std::vector<std::size_t> defIndex;
  for (const E e : def) {
    defIndex.push_back(indexOf(e));
    PP5_CHECK_LT(defIndex.back(), EnumNames<E>::names.size());
  }
  schema.choicesIndex(
      key, enumNameList<E>(), defIndex,
      [field](const std::vector<std::size_t>& v) {
        field->clear();
        for (const std::size_t i : v) field->push_back(EnumNames<E>::names[i].first);
      },
      [field, indexOf] {
        std::vector<std::size_t> v;
        for (const E e : *field) v.push_back(indexOf(e));
        return v;
      },
      doc);
}

}  // namespace pp5
