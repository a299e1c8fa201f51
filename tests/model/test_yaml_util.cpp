// The YAML reader every file of ours goes through (model/yaml_util.h): bounded in bytes and in
// nodes with its aliases expanded, regular files only, and messages that name the line and say
// what a person would need to know (a tab in the indentation, the key they probably meant).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>

#include "model/stage.h"
#include "model/yaml_util.h"

using idm::model::InputError;
using idm::model::load_yaml_file;
using idm::model::load_yaml_text;
using idm::model::unknown_name;
using idm::model::YamlLimits;

namespace {

std::string error_of(const std::string& text, const YamlLimits& limits = {}) {
  try {
    load_yaml_text(text, "f.yaml", limits);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// `levels` anchors, each a list of `fan` aliases of the one before: fan^levels nodes expanded.
std::string alias_bomb(int levels, int fan) {
  std::string text = "a0: &a0 [x]\n";
  for (int k = 1; k <= levels; ++k) {
    text += "a" + std::to_string(k) + ": &a" + std::to_string(k) + " [";
    for (int j = 0; j < fan; ++j) text += (j ? ", *a" : "*a") + std::to_string(k - 1);
    text += "]\n";
  }
  return text;
}

}  // namespace

TEST(Yaml, AnAliasBombIsRefusedNamingItBeforeItIsWalked) {
  for (int levels : {6, 9, 12, 30}) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string e = error_of(alias_bomb(levels, 9));
    EXPECT_NE(e.find("alias"), std::string::npos) << e;
    EXPECT_NE(e.find("f.yaml"), std::string::npos) << e;
    // No timing assertion: the count of nodes walked is what is bounded; the duration is shown.
    std::printf("%d levels: refused after %.3f s\n", levels,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
}

TEST(Yaml, AliasesWithinTheBoundStillRead) {
  // A config that shares a stage between axes through an anchor reads as before.
  EXPECT_EQ(error_of("s: &s {a: 1, b: 2}\nx: *s\ny: *s\n"), "");
  // Exactly at the bound and one past it.
  const YamlLimits small{1 << 20, 12};
  EXPECT_EQ(error_of("a: [1, 2, 3, 4, 5]\nb: [1, 2, 3, 4]\n", small), "");
  EXPECT_NE(error_of("a: [1, 2, 3, 4, 5]\nb: [1, 2, 3, 4, 5]\n", small), "");
}

TEST(Yaml, TextPastItsByteLimitIsRefusedBeforeParsing) {
  const std::string e = error_of(std::string(2000, '#'), {1000, 100});
  EXPECT_NE(e.find("2000 bytes"), std::string::npos) << e;
  EXPECT_NE(e.find("1000"), std::string::npos) << e;
}

TEST(Yaml, AFifoIsRefusedAtOnceNeverWaitedOn) {
  char dir[] = "/tmp/idm-yaml-XXXXXX";
  ASSERT_NE(::mkdtemp(dir), nullptr);
  const std::string fifo = std::string(dir) + "/stage.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string e;
  try {
    load_yaml_file(fifo);  // would block forever on a plain open
  } catch (const InputError& ex) {
    e = ex.what();
  }
  EXPECT_NE(e.find("not a regular file"), std::string::npos) << e;
  EXPECT_NE(e.find(fifo), std::string::npos) << e;
  ::unlink(fifo.c_str());
  ::rmdir(dir);
}

TEST(Yaml, ATabInTheIndentationIsSaidSo) {
  const std::string e = error_of("stage:\n\tslider_mass_kg: 0.1\n");
  EXPECT_NE(e.find("tab"), std::string::npos) << e;
  EXPECT_NE(e.find("line 2"), std::string::npos) << e;
  EXPECT_EQ(error_of("stage:\n  slider_mass_kg: 0.1  # a\ttab in a comment is fine\n"), "");
}

TEST(Yaml, AnUnknownNameSuggestsTheNearestAllowedOneOnlyWhenNear) {
  const std::vector<std::string> allowed = {"max_retries", "tolerance_m", "dwell_s", "hold_s"};
  EXPECT_NE(unknown_name("max_retry", allowed).find("did you mean 'max_retries'?"),
            std::string::npos);
  EXPECT_NE(unknown_name("Tolerance_M", allowed).find("did you mean 'tolerance_m'?"),
            std::string::npos);
  EXPECT_EQ(unknown_name("frobnicate", allowed).find("did you mean"), std::string::npos);
  EXPECT_EQ(unknown_name("xy", allowed).find("did you mean"), std::string::npos);
  // Generated typos: one letter dropped, doubled or changed in an allowed name is always traced
  // back to it (no other allowed name is as near).
  std::mt19937 rng(4);
  for (int k = 0; k < 500; ++k) {
    const std::string& name = allowed[rng() % allowed.size()];
    std::string typo = name;
    const std::size_t at = rng() % typo.size();
    switch (rng() % 3) {
      case 0:
        typo.erase(at, 1);
        break;
      case 1:
        typo.insert(at, 1, typo[at]);
        break;
      default:
        typo[at] = typo[at] == 'q' ? 'z' : 'q';
    }
    EXPECT_NE(unknown_name(typo, allowed).find("did you mean '" + name + "'?"), std::string::npos)
        << typo << " -> " << unknown_name(typo, allowed);
  }
}
