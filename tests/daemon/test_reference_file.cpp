// An axis's reference kept across restarts (daemon/reference_file.h): the file, and when it holds.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

#include "daemon/reference_file.h"
#include "model/stage.h"

namespace {

using namespace idm::daemon;
namespace fs = std::filesystem;

fs::path temp_path(const std::string& name) {
  return fs::temp_directory_path() / ("idmd-ref-" + std::to_string(::getpid()) + "-" + name);
}

SavedReference referenced(std::uint64_t epoch, std::int64_t offset_counts, double offset_m) {
  SavedReference r;
  r.referenced = true;
  r.origin.has_epoch = true;
  r.origin.epoch = epoch;
  r.origin.offset_counts = offset_counts;
  r.offset_m = offset_m;
  return r;
}

TEST(ReferenceFile, RoundTripsExactlyTheWholeEpochAndTheOffset) {
  const fs::path file = temp_path("roundtrip.yaml");
  // An epoch above the signed 64-bit range, an offset with all 17 digits, a negative count.
  SavedReference saved = referenced(18446744073709551557ull, -987654321012, -4.9012345678901234e-3);
  saved.user_offset_m = 7.1234567890123456;  // POSition:SET's offset, kept with it
  save_reference(file.string(), saved, "x");
  const SavedReference loaded = load_reference(file.string());
  EXPECT_TRUE(loaded == saved);
  EXPECT_EQ(loaded.offset_m, saved.offset_m);            // bit for bit
  EXPECT_EQ(loaded.user_offset_m, saved.user_offset_m);  // bit for bit
  EXPECT_FALSE(fs::exists(file.string() + ".tmp"));
  fs::remove(file);
}

TEST(ReferenceFile, ABadFileNamesTheFileTheLineAndTheKey) {
  const fs::path file = temp_path("bad.yaml");
  const std::string good = reference_text(referenced(7, 0, 1e-3), "x");
  const struct {
    std::string from, to, expect;
  } cases[] = {
      {"referenced: true", "referenced: maybe", "referenced"},
      {"count_epoch: \"7\"", "count_epoch: \"-7\"", "count_epoch"},
      {"count_epoch: \"7\"", "count_epoch: \"7x\"", "count_epoch"},
      {"offset_m: 0.001", "offset_m: 1e300", "offset_m"},
      {"offset_m: 0.001", "offset_m: .nan", "offset_m"},
      {"offset_counts: 0\n", "", "offset_counts"},
      {"user_offset_m: 0\n", "user_offset_m: 10.5\n", "user_offset_m"},  // allowed [-10, 10]
      {"user_offset_m: 0\n", "user_offset_m: .nan\n", "user_offset_m"},
  };
  for (const auto& c : cases) {
    std::string text = good;
    ASSERT_NE(text.find(c.from), std::string::npos) << c.from << " in\n" << text;
    text.replace(text.find(c.from), c.from.size(), c.to);
    std::ofstream(file) << text;
    try {
      load_reference(file.string());
      ADD_FAILURE() << "accepted: " << c.to;
    } catch (const idm::model::InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(file.string()), std::string::npos) << what;
      EXPECT_NE(what.find(c.expect), std::string::npos) << what;
    }
  }
  // A file written before the user offset: it loads, with none.
  std::string old_file = good;
  old_file.erase(old_file.find("user_offset_m: 0\n"), std::string("user_offset_m: 0\n").size());
  std::ofstream(file) << old_file;
  EXPECT_EQ(load_reference(file.string()).user_offset_m, 0.0);
  std::ofstream(file) << "referenced: [";
  EXPECT_THROW(load_reference(file.string()), idm::model::InputError);
  fs::remove(file);
}

TEST(ReferenceFile, HoldsOnlyForTheSameCountEpoch) {
  const SavedReference saved = referenced(42, 5, 1e-3);
  idm::drivers::CountOrigin now{true, 42, 0};
  EXPECT_EQ(reference_holds(saved, now), "");
  now.epoch = 43;
  EXPECT_NE(reference_holds(saved, now).find("started over"), std::string::npos);
  now = {false, 42, 0};
  EXPECT_NE(reference_holds(saved, now).find("no count epoch"), std::string::npos);
  SavedReference no_epoch = saved;
  no_epoch.origin.has_epoch = false;
  EXPECT_NE(reference_holds(no_epoch, {true, 42, 0}).find("no count epoch"), std::string::npos);
  SavedReference unreferenced = saved;
  unreferenced.referenced = false;
  EXPECT_NE(reference_holds(unreferenced, {true, 42, 0}).find("not referenced"), std::string::npos);
}

TEST(ReferenceFile, AFailedSaveNamesTheFile) {
  // The file whole or not at all is recording::write_file_durably's (tested with the datasets).
  const std::string file = "/nonexistent-idmd-dir/ref.yaml";
  try {
    save_reference(file, referenced(2, 0, 3e-3), "x");
    ADD_FAILURE() << "saved into a directory that does not exist";
  } catch (const std::system_error& e) {
    EXPECT_NE(std::string(e.what()).find(file), std::string::npos) << e.what();
  }
}

}  // namespace
