// Files that survive a crash whole or not at all: written to a temporary name in their directory,
// fsynced, renamed over the final name, and the directory fsynced. The dataset writer and every
// report of the analysis write through these.
#pragma once

#include <filesystem>
#include <string_view>

namespace idm::recording {

// Writes `content` to `final_path`: a reader sees the old file or the new one, never part of one.
// On failure the temporary file is removed and `final_path` is as it was. Throws std::system_error
// naming the file.
void write_file_durably(const std::filesystem::path& final_path, std::string_view content);

// Creates `dir` (and missing parents) and makes the new entries durable. Throws std::system_error.
void create_directory_durably(const std::filesystem::path& dir);

}  // namespace idm::recording
