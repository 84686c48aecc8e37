// geodesic load: register a mesh, by its path on the server or by upload.
#include <openssl/evp.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <vector>

#include "absl/strings/str_format.h"
#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

// The size and lower-case hex SHA-256 of a file, which an upload declares
// before its bytes.
bool SizeAndSha256(const std::string& path, uint64_t* size, std::string* sha256) {
  std::ifstream in(path, std::ios::binary);
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  if (!in || !ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1) return false;
  std::vector<char> buffer(1 << 20);
  *size = 0;
  while (in) {
    in.read(buffer.data(), buffer.size());
    if (EVP_DigestUpdate(ctx.get(), buffer.data(), in.gcount()) != 1) return false;
    *size += in.gcount();
  }
  if (!in.eof()) return false;
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  if (EVP_DigestFinal_ex(ctx.get(), digest, &length) != 1) return false;
  sha256->clear();
  for (unsigned int i = 0; i < length; ++i) absl::StrAppendFormat(sha256, "%02x", digest[i]);
  return true;
}

int CmdLoad(const Common& c, const std::string& path, const std::string& upload, bool repair) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::Mesh resp;
  grpc::Status s;
  if (!upload.empty()) {
    std::ifstream in(upload, std::ios::binary);
    if (!in) return FailText("cannot read " + upload);
    // The format is the file's extension: say so here rather than send the
    // whole path as a format.
    const std::string ext = std::filesystem::path(upload).extension().string();
    if (ext.size() < 2) {
      return FailText(upload +
                      " has no extension naming its format (.obj, .off, .ply, .stl or .surf.gii)");
    }
    // The server registers the upload only if exactly these bytes arrive:
    // a file changed while it is sent is refused, not half registered.
    uint64_t total = 0;
    std::string sha256;
    if (!SizeAndSha256(upload, &total, &sha256)) return FailText("cannot read " + upload);
    if (total == 0) return FailText(upload + " is empty");
    auto writer = stub->UploadMesh(&ctx, &resp);
    std::vector<char> buffer(1 << 20);
    bool first = true;
    while (in || first) {
      in.read(buffer.data(), buffer.size());
      v1::UploadMeshRequest chunk;
      if (first) {
        chunk.set_name(c.mesh);
        chunk.set_format(ext.substr(1));
        chunk.set_repair_non_manifold(repair);
        chunk.set_total_bytes(total);
        chunk.set_sha256(sha256);
        first = false;
      }
      chunk.set_data(buffer.data(), in.gcount());
      if (!writer->Write(chunk)) break;
    }
    writer->WritesDone();
    s = writer->Finish();
  } else {
    v1::RegisterMeshRequest req;
    req.set_name(c.mesh);
    req.set_path(path);
    req.set_repair_non_manifold(repair);
    s = stub->RegisterMesh(&ctx, req, &resp);
  }
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson(server::MeshJson<Json>(resp));
  } else {
    std::printf("registered %s: %lu vertices, %lu faces, fingerprint %s%s\n", resp.name().c_str(),
                resp.diagnostics().vertices(), resp.diagnostics().faces(),
                resp.fingerprint().c_str(), resp.restored() ? " (restored from its snapshot)" : "");
  }
  return 0;
}

}  // namespace

Command AddLoad(CLI::App& app, Common& c, const CLI::Option* mesh_option) {
  auto* sub =
      app.add_subcommand("load", "register a mesh (server-side path under --mesh-root, or upload)");
  struct Args {
    std::string path, upload;
    bool repair = false;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("path", a->path, "path relative to the server's --mesh-root");
  sub->add_option("--upload", a->upload, "upload this local file instead");
  sub->add_flag("--repair-non-manifold", a->repair,
                "split non-manifold vertices into one copy per fan (listed) instead of refusing");
  return {sub, [&c, a, mesh_option] {
            // 'geodesic load kitten.off' registers 'kitten', not the default mesh.
            if (mesh_option->count() == 0) {
              c.mesh =
                  std::filesystem::path(a->upload.empty() ? a->path : a->upload).stem().string();
            }
            return CmdLoad(c, a->path, a->upload, a->repair);
          }};
}

}  // namespace geodesic::cli
