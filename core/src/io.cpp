#include "flashtwin/core/io.hpp"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "flashtwin/core/errors.hpp"

namespace flashtwin {

namespace fs = std::filesystem;

std::string read_text_file(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw IoError(path + ": file not found");
  if (fs::is_directory(path, ec)) throw IoError(path + ": expected a file, got a directory");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open for reading");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write_text_file(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".part";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw IoError(path + ": cannot open for writing");
    out << text;
    out.flush();
    if (!out) throw IoError(path + ": write failed");
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw IoError(path + ": cannot move the written file into place");
  }
}

void ensure_directory(const std::string& path) {
  std::error_code ec;
  fs::create_directories(path, ec);
  if (ec || !fs::is_directory(path))
    throw IoError(path + ": cannot create output directory (" + ec.message() + ")");
}

}  // namespace flashtwin
