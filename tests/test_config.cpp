#include <gtest/gtest.h>

#include <fstream>
#include <filesystem>

#include "core/config.hpp"
#include "core/error.hpp"

namespace {

struct Demo {
  bool flag;
  int count;
  double gain;
  std::string name;
  std::string mode;
  glm::dvec3 spacing;
  glm::ivec3 dims;
};

struct Fixture : ::testing::Test {
  Demo d{};
  pp5::ConfigSchema schema;
  void SetUp() override {
    schema.section("a", "Section a.");
    schema.option("a.flag", &d.flag, false, "A flag.");
    schema.option("a.count", &d.count, 3, 1, 10, "A count.");
    schema.option("a.gain", &d.gain, 0.5, 0.0, 1.0, "A gain.");
    schema.section("a.b", "Nested section.");
    schema.option("a.b.name", &d.name, "x", "A name.");
    schema.choice("a.b.mode", &d.mode, "fast", {"fast", "slow"}, "A mode.");
    schema.option("a.b.spacing", &d.spacing, {1.0, 1.0, 1.0}, 0.001, 10.0, "Spacing.");
    schema.option("a.b.dims", &d.dims, {4, 5, 6}, 1, 100, "Dims.");
  }
  std::string errorOf(const std::string& text) {
    try {
      schema.loadString(text, "cfg.toml");
    } catch (const pp5::InputError& e) {
      return e.what();
    }
    return "";
  }
};

TEST_F(Fixture, DefaultsAreAppliedOnRegistration) {
  EXPECT_FALSE(d.flag);
  EXPECT_EQ(d.count, 3);
  EXPECT_DOUBLE_EQ(d.gain, 0.5);
  EXPECT_EQ(d.name, "x");
  EXPECT_EQ(d.mode, "fast");
  EXPECT_EQ(d.dims, glm::ivec3(4, 5, 6));
}

TEST_F(Fixture, LoadsEveryTypeFromTablesAndDottedKeys) {
  schema.loadString(
      "[a]\nflag = true\ncount = 7\ngain = 1\n[a.b]\nname = \"doll\"\nmode = \"slow\"\n"
      "spacing = [0.5, 0.25, 2]\ndims = [1, 2, 3]\n",
      "cfg.toml");
  EXPECT_TRUE(d.flag);
  EXPECT_EQ(d.count, 7);
  EXPECT_DOUBLE_EQ(d.gain, 1.0);  // an integer is accepted where a float is expected
  EXPECT_EQ(d.name, "doll");
  EXPECT_EQ(d.mode, "slow");
  EXPECT_EQ(d.spacing, glm::dvec3(0.5, 0.25, 2.0));
  EXPECT_EQ(d.dims, glm::ivec3(1, 2, 3));
  schema.applyDefaults();
  EXPECT_EQ(d.count, 3);
}

// What a file or override assigned, even to the default value, is known (a
// value derived at run time must not replace it); a rejected value is not
// assigned, and applyDefaults forgets them all.
TEST_F(Fixture, RemembersWhichKeysWereAssigned) {
  EXPECT_FALSE(schema.assigned("a.count"));
  schema.loadString("[a]\ncount = 3\n[a.b]\nname = \"y\"\n", "cfg.toml");
  schema.set("a.gain=0.25");
  EXPECT_TRUE(schema.assigned("a.count"));  // the default value, but given
  EXPECT_TRUE(schema.assigned("a.b.name"));
  EXPECT_TRUE(schema.assigned("a.gain"));
  EXPECT_FALSE(schema.assigned("a.flag"));
  EXPECT_FALSE(schema.assigned("a.b"));  // a table, not an option
  EXPECT_THROW(schema.set("a.b.dims=[0, 1, 1]"), pp5::InputError);
  EXPECT_FALSE(schema.assigned("a.b.dims"));
  schema.applyDefaults();
  EXPECT_FALSE(schema.assigned("a.count"));
  EXPECT_FALSE(schema.assigned("a.gain"));
}

TEST_F(Fixture, UnknownKeyNamesFileKeyAndLine) {
  const std::string e = errorOf("[a]\ncount = 2\n\ncuont = 3\n");
  EXPECT_NE(e.find("cfg.toml:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key 'a.cuont'"), std::string::npos) << e;
  EXPECT_NE(errorOf("[zzz]\nq = 1\n").find("unknown key 'zzz'"), std::string::npos);
}

TEST_F(Fixture, WrongTypeAndRangeAreErrorsWithLine) {
  std::string e = errorOf("[a]\ncount = \"three\"\n");
  EXPECT_NE(e.find("cfg.toml:2:"), std::string::npos) << e;
  EXPECT_NE(e.find("'a.count' must be an integer"), std::string::npos) << e;
  e = errorOf("[a]\n\ncount = 11\n");
  EXPECT_NE(e.find("cfg.toml:3:"), std::string::npos) << e;
  EXPECT_NE(e.find("out of range [1, 10]"), std::string::npos) << e;
  e = errorOf("a.gain = 1.5\n");
  EXPECT_NE(e.find("out of range"), std::string::npos) << e;
  e = errorOf("a.b.mode = \"medium\"\n");
  EXPECT_NE(e.find("not one of: fast, slow"), std::string::npos) << e;
  e = errorOf("a.b.spacing = [1, 2]\n");
  EXPECT_NE(e.find("array of 3 numbers"), std::string::npos) << e;
  e = errorOf("a.b.dims = [1, 2.5, 3]\n");
  EXPECT_NE(e.find("array of 3 integers"), std::string::npos) << e;
  e = errorOf("a.flag = 1\n");
  EXPECT_NE(e.find("true or false"), std::string::npos) << e;
  // A rejected file leaves earlier values alone only up to the bad key; callers
  // stop on the error, so only the message matters here.
}

TEST_F(Fixture, SyntaxErrorNamesLine) {
  const std::string e = errorOf("[a]\ncount = = 2\n");
  EXPECT_NE(e.find("cfg.toml:2:"), std::string::npos) << e;
}

TEST_F(Fixture, SetOverridesAcceptBareWordsAndCheckRanges) {
  schema.set("a.b.name=forearm");
  EXPECT_EQ(d.name, "forearm");
  schema.set("a.count = 9");
  EXPECT_EQ(d.count, 9);
  schema.set("a.b.spacing=[2,2,2]");
  EXPECT_EQ(d.spacing, glm::dvec3(2.0));
  EXPECT_THROW(schema.set("a.count=0"), pp5::InputError);
  EXPECT_THROW(schema.set("a.nothing=1"), pp5::InputError);
  EXPECT_THROW(schema.set("novalue"), pp5::InputError);
}

// A value in another encoding than UTF-8 is refused, not re-encoded: a folder
// named in Latin-1 ("caf\xe9") was written as "caf".
TEST_F(Fixture, SetRefusesBytesThatAreNotUtf8) {
  for (const std::string bad : {"a.b.name=caf\xe9", "a.b.name=\"caf\xe9\"", "a.b.name=\xc0\xaf", "a.b.name=\xed\xa0\x80",
                                "a.b.name=x\xe2\x82"}) {
    try {
      schema.set(bad);
      ADD_FAILURE() << "accepted " << bad;
    } catch (const pp5::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("not UTF-8"), std::string::npos) << e.what();
    }
  }
  schema.set("a.b.name=caf\xc3\xa9");  // é in UTF-8
  EXPECT_EQ(d.name, "caf\xc3\xa9");
  schema.set("a.b.name=\xf0\x9f\x94\x8a");  // U+1F50A
  EXPECT_EQ(d.name, "\xf0\x9f\x94\x8a");
}

TEST_F(Fixture, TomlRoundTripsTheCurrentValues) {
  schema.set("a.gain=0.125");
  schema.set("a.b.name=with \"quotes\"");
  schema.set("a.b.dims=[9,8,7]");
  const std::string text = schema.toToml();
  Demo before = d;
  schema.applyDefaults();
  schema.loadString(text, "roundtrip");
  EXPECT_DOUBLE_EQ(d.gain, before.gain);
  EXPECT_EQ(d.name, before.name);
  EXPECT_EQ(d.dims, before.dims);
  EXPECT_EQ(d.spacing, before.spacing);
}

TEST_F(Fixture, MarkdownListsEveryOptionUnderItsSection) {
  const std::string md = schema.markdown();
  for (const auto& e : schema.entries()) EXPECT_NE(md.find("`" + e.key + "`"), std::string::npos) << e.key;
  // Nested keys go to the most specific section.
  EXPECT_LT(md.find("## [a.b]"), md.find("`a.b.name`"));
  EXPECT_GT(md.find("## [a.b]"), md.find("`a.count`"));
}

TEST_F(Fixture, MissingFileIsAnInputError) {
  try {
    schema.loadFile("/nonexistent/cfg.toml");
    FAIL();
  } catch (const pp5::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/cfg.toml"), std::string::npos);
  }
}

}  // namespace
