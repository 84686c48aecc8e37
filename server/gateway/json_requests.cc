// The gateway's JSON readers (json_requests.h).
#include "server/gateway/json_requests.h"

#include <algorithm>
#include <cstdlib>
#include <optional>
#include <set>
#include <string_view>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/str_join.h"
#include "google/protobuf/util/json_util.h"

namespace geodesic::server::gateway {
namespace {

// The deepest nesting of arrays and objects in JSON text (brackets inside
// strings do not count). Reading and copying a value recurses once per
// level, so a body of 100,000 nested brackets would overflow the stack.
size_t NestingDepth(std::string_view text) {
  size_t depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      deepest = std::max(deepest, ++depth);
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
  return deepest;
}

constexpr size_t kMaxNesting = 64;

// Reads a JSON text for the first key an object gives twice, building
// nothing. A DOM parse with a callback would do the same, but the library's
// callback parser looks through the enclosing array at each object's end,
// which made an array of many small objects take quadratic time.
class DuplicateKeyFinder : public nlohmann::json_sax<json> {
 public:
  std::optional<std::string> duplicate;

  bool null() override { return true; }
  bool boolean(bool) override { return true; }
  bool number_integer(number_integer_t) override { return true; }
  bool number_unsigned(number_unsigned_t) override { return true; }
  bool number_float(number_float_t, const string_t&) override { return true; }
  bool string(string_t&) override { return true; }
  bool binary(binary_t&) override { return true; }
  bool start_object(std::size_t) override {
    keys_.emplace_back();
    return true;
  }
  bool key(string_t& key) override {
    if (keys_.back().insert(key).second) return true;
    duplicate = key;
    return false;
  }
  bool end_object() override {
    keys_.pop_back();
    return true;
  }
  bool start_array(std::size_t) override { return true; }
  bool end_array() override { return true; }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override {
    return false;
  }

 private:
  std::vector<std::set<std::string>> keys_;  // of the objects open, innermost last
};

}  // namespace

grpc::Status ParseBody(const HttpRequest& req, json* body) {
  if (req.body.empty()) {
    *body = json::object();
    return grpc::Status::OK;
  }
  if (NestingDepth(req.body) > kMaxNesting) {
    return Invalid(absl::StrFormat("request body nests arrays and objects deeper than %u levels",
                                   kMaxNesting));
  }
  // A key given twice would silently take its last value: which one the
  // client meant is unknown, so the body is refused.
  DuplicateKeyFinder finder;
  json::sax_parse(req.body, &finder, json::input_format_t::json, /*strict=*/true,
                  /*ignore_comments=*/false);
  if (finder.duplicate) {
    return Invalid(absl::StrFormat("request body gives the key \"%s\" more than once",
                                   absl::CHexEscape(finder.duplicate->substr(0, 80))));
  }
  *body = json::parse(req.body, nullptr, /*allow_exceptions=*/false);
  if (body->is_discarded()) return Invalid("request body is not valid JSON");
  if (!body->is_object()) return Invalid("request body must be a JSON object");
  return grpc::Status::OK;
}

grpc::Status OnlyKeys(const json& body, const std::vector<std::string>& keys) {
  if (!body.is_object()) return grpc::Status::OK;  // the handler names what it expected
  for (const auto& [key, value] : body.items()) {
    if (std::find(keys.begin(), keys.end(), key) != keys.end()) continue;
    return Invalid(absl::StrFormat("unknown key %s in the body; this call takes: %s", Quote(key),
                                   absl::StrJoin(keys, ", ")));
  }
  return grpc::Status::OK;
}

grpc::Status BodyEpsilon(const json& body, double* eps) {
  *eps = 0;
  for (const char* key : {"eps", "epsilon"}) {
    auto it = body.find(key);
    if (it == body.end() || it->is_null()) continue;
    if (!it->is_number()) return Invalid(absl::StrFormat("\"%s\" must be a number", key));
    const double value = it->get<double>();
    if (*eps != 0 && value != *eps) {
      return Invalid(absl::StrFormat("\"eps\" (%g) and \"epsilon\" (%g) disagree", *eps, value));
    }
    *eps = value;
  }
  return grpc::Status::OK;
}

grpc::Status QueryEpsilon(const HttpRequest& req, double* eps) {
  *eps = 0;
  if (!req.has_param("eps")) return grpc::Status::OK;
  const std::string text = req.param("eps");
  char* end = nullptr;
  *eps = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size()) {
    return Invalid(absl::StrFormat("query parameter eps=%s is not a number", text));
  }
  return grpc::Status::OK;
}

grpc::Status BodyMaxError(const json& body, double* max_error) {
  *max_error = 0;
  auto it = body.find("max_error");
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (!it->is_number()) return Invalid("\"max_error\" must be a number");
  *max_error = it->get<double>();
  return grpc::Status::OK;
}

grpc::Status QueryMaxError(const HttpRequest& req, double* max_error) {
  *max_error = 0;
  if (!req.has_param("max_error")) return grpc::Status::OK;
  const std::string text = req.param("max_error");
  char* end = nullptr;
  *max_error = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size()) {
    return Invalid(absl::StrFormat("query parameter max_error=%s is not a number", text));
  }
  return grpc::Status::OK;
}

grpc::Status BoolField(const json& body, const char* key, bool* out) {
  *out = false;
  auto it = body.find(key);
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (!it->is_boolean()) return Invalid(absl::StrFormat("\"%s\" must be true or false", key));
  *out = it->get<bool>();
  return grpc::Status::OK;
}

grpc::Status MessageOf(const json& body, google::protobuf::Message* out) {
  google::protobuf::util::JsonParseOptions options;
  options.ignore_unknown_fields = true;
  const auto s = google::protobuf::util::JsonStringToMessage(Dump(body), out, options);
  if (s.ok()) return grpc::Status::OK;
  return Invalid("request body: " + std::string(s.message().data(), s.message().size()));
}

grpc::Status ArrayField(const json& body, const char* key, const json** out) {
  auto it = body.find(key);
  if (it == body.end() || !it->is_array()) {
    return Invalid(absl::StrFormat("\"%s\" must be an array", key));
  }
  *out = &*it;
  return grpc::Status::OK;
}

bool WantsNpy(const HttpRequest& http) {
  return absl::StrContains(absl::AsciiStrToLower(http.header("Accept")), "application/x-npy");
}

grpc::Status BodyDtype(const json& body, v1::MatrixDtype* dtype) {
  *dtype = v1::MATRIX_DTYPE_DEFAULT;
  auto it = body.find("dtype");
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (it->is_string() && it->get<std::string>() == "float32") {
    *dtype = v1::MATRIX_DTYPE_FLOAT32;
  } else if (it->is_string() && it->get<std::string>() == "float64") {
    *dtype = v1::MATRIX_DTYPE_FLOAT64;
  } else {
    return Invalid(
        absl::StrFormat("\"dtype\" must be \"float32\" or \"float64\", got %s", Quote(*it)));
  }
  return grpc::Status::OK;
}

}  // namespace geodesic::server::gateway
