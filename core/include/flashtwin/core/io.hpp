#pragma once
// Small file helpers with the project's error messages.
#include <string>

namespace flashtwin {

/// Whole file as text. @throws IoError when missing, a directory, or unreadable.
std::string read_text_file(const std::string& path);

/// Writes text or binary bytes atomically (temporary file + rename), so a failed run never
/// leaves a half-written output behind. @throws IoError when the file cannot be written.
void write_text_file(const std::string& path, const std::string& text);

/// Creates a directory (and parents). @throws IoError when it cannot be created.
void ensure_directory(const std::string& path);

}  // namespace flashtwin
