// Crash-safe writes never write through a link another user planted: a stale temporary name that
// is a link is removed (its target untouched), a link at the final name is replaced (its target
// untouched), and writes below a directory held open never follow a component swapped for a link.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "recording/durable_file.h"

namespace fs = std::filesystem;
using idm::recording::DirFd;
using idm::recording::write_file_durably;
using idm::recording::write_file_durably_at;

namespace {

struct TempDir {
  fs::path path;
  TempDir() {
    char t[] = "/tmp/idm-durable-XXXXXX";
    path = ::mkdtemp(t);
  }
  ~TempDir() { fs::remove_all(path); }
};

std::string read(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST(DurableFile, ALinkPlantedAtTheTemporaryNameIsNeverWrittenThrough) {
  TempDir t;
  const fs::path victim = t.path / "victim";
  std::ofstream(victim) << "keep";
  fs::create_symlink(victim, t.path / ".calibration.txt.tmp");
  write_file_durably(t.path / "calibration.txt", "new");
  EXPECT_EQ(read(victim), "keep");
  EXPECT_EQ(read(t.path / "calibration.txt"), "new");
  EXPECT_FALSE(fs::exists(fs::symlink_status(t.path / ".calibration.txt.tmp")));
}

TEST(DurableFile, ALinkAtTheFinalNameIsReplacedNotFollowed) {
  TempDir t;
  const fs::path victim = t.path / "victim";
  std::ofstream(victim) << "keep";
  fs::create_symlink(victim, t.path / "plan.yaml");
  write_file_durably(t.path / "plan.yaml", "new");
  EXPECT_EQ(read(victim), "keep");
  EXPECT_FALSE(fs::is_symlink(t.path / "plan.yaml"));
  EXPECT_EQ(read(t.path / "plan.yaml"), "new");
}

TEST(DurableFile, BelowADirectoryHeldOpenASwappedComponentIsNeverFollowed) {
  TempDir t;
  fs::create_directories(t.path / "ds" / "trials");
  fs::create_directories(t.path / "elsewhere");
  const DirFd ds = DirFd::open(t.path / "ds");
  // The dataset directory moved away and a link put in its place: writes go on into it.
  fs::rename(t.path / "ds", t.path / "moved");
  fs::create_directory_symlink(t.path / "elsewhere", t.path / "ds");
  write_file_durably_at(ds, "trials/a.csv", "x", "ds");
  EXPECT_EQ(read(t.path / "moved" / "trials" / "a.csv"), "x");
  EXPECT_TRUE(fs::is_empty(t.path / "elsewhere"));
  // A component below it that is a link is refused.
  fs::remove_all(t.path / "moved" / "trials");
  fs::create_directory_symlink(t.path / "elsewhere", t.path / "moved" / "trials");
  EXPECT_THROW(write_file_durably_at(ds, "trials/b.csv", "x", "ds"), std::system_error);
  EXPECT_TRUE(fs::is_empty(t.path / "elsewhere"));
  // Paths that leave it are refused.
  for (const char* bad : {"../x", "/etc/x", "a//b", "./x", ""})
    EXPECT_THROW(write_file_durably_at(ds, bad, "x", "ds"), std::system_error) << bad;
}
