// The connection to one geodesicd: channel, TLS, the bearer token, deadlines,
// retries, and failures as GeodesicError subclasses. What the calls carry is
// not its business.
import * as grpc from "@grpc/grpc-js";
import { fromGrpcError } from "./errors";
import { RetryPolicy, withRetries } from "./retry";
import { Methods, MethodName, methods, RequestOf, ResponseOf } from "./wire";

export interface TransportOptions {
  address: string;
  timeout: number;
  token?: string | undefined;
  rootCertificates?: Buffer | undefined;
  privateKey?: Buffer | undefined;
  certificateChain?: Buffer | undefined;
  retry: RetryPolicy;
  maxMessageBytes: number;
}

// Adds the token to every call. grpc-js refuses call credentials on a
// plaintext channel, and the daemon (server/limits/client_key.cc) wants
// exactly one "authorization: Bearer <token>" header on every call,
// plaintext or TLS: an interceptor sets it, the same way on both.
function bearer(token: string): grpc.Interceptor {
  return (options, nextCall) => new grpc.InterceptingCall(nextCall(options), {
    start(metadata, listener, next) {
      metadata.set("authorization", `Bearer ${token}`);
      next(metadata, listener);
    },
  });
}

/** A channel to address; every call goes through it. */
export class Transport {
  readonly client: grpc.Client;
  readonly methods: Methods;
  /** Each call's deadline, seconds. */
  timeout: number;
  retry: RetryPolicy;

  constructor(options: TransportOptions) {
    const credentials = options.rootCertificates !== undefined
      ? grpc.credentials.createSsl(options.rootCertificates, options.privateKey ?? null,
        options.certificateChain ?? null)
      : grpc.credentials.createInsecure();
    const backoffMs = (seconds: number): number => Math.max(1, Math.round(seconds * 1000));
    this.client = new grpc.Client(options.address, credentials, {
      "grpc.max_receive_message_length": options.maxMessageBytes,
      "grpc.max_send_message_length": options.maxMessageBytes,
      // gRPC's own reconnect backoff would otherwise grow past the retries'
      // (to minutes), failing every retry fast.
      "grpc.initial_reconnect_backoff_ms": backoffMs(options.retry.initialBackoff),
      "grpc.max_reconnect_backoff_ms": backoffMs(options.retry.maxBackoff),
      interceptors: options.token ? [bearer(options.token)] : [],
    });
    this.methods = methods();
    this.timeout = options.timeout;
    this.retry = options.retry;
  }

  close(): void {
    this.client.close();
  }

  private metadata(mesh: string | undefined): grpc.Metadata {
    const metadata = new grpc.Metadata();
    // Proxies route by this header, so that a mesh's queries reach the
    // replicas that hold its graph.
    if (mesh) metadata.set("x-geodesic-mesh", mesh);
    return metadata;
  }

  private options(deadline: boolean): grpc.CallOptions {
    return deadline ? { deadline: Date.now() + this.timeout * 1000 } : {};
  }

  /** One attempt of a unary method. */
  unaryOnce<K extends MethodName>(name: K, request: RequestOf<K>,
    mesh: string | undefined): Promise<ResponseOf<K>> {
    const m = this.methods[name];
    return new Promise((resolve, reject) => {
      this.client.makeUnaryRequest(m.path, m.requestSerialize, m.responseDeserialize, request,
        this.metadata(mesh), this.options(true), (error, response) => {
          if (error) reject(fromGrpcError(error, name));
          else if (response === undefined) reject(new Error(`${name}: no answer and no error`));
          else resolve(response);
        });
    });
  }

  /** A unary method, retried per the policy. */
  unary<K extends MethodName>(name: K, request: RequestOf<K>,
    mesh: string | undefined): Promise<ResponseOf<K>> {
    return withRetries(this.retry, () => this.unaryOnce(name, request, mesh));
  }

  /** The answers of a server-streaming method, one attempt: failures become GeodesicError,
   * and leaving the loop early (break, an exception) cancels the call, so that the server
   * stops sending to nobody. deadline: false for a call with none (a watch). */
  async *stream<K extends MethodName>(name: K, request: RequestOf<K>, mesh: string | undefined,
    deadline = true): AsyncGenerator<ResponseOf<K>, void, undefined> {
    const m = this.methods[name];
    const call = this.client.makeServerStreamRequest(m.path, m.requestSerialize,
      m.responseDeserialize, request, this.metadata(mesh), this.options(deadline));
    let done = false;
    try {
      for await (const item of call as AsyncIterable<ResponseOf<K>>) yield item;
      done = true;
    } catch (e) {
      done = true;
      throw fromGrpcError(e, name);
    } finally {
      if (!done) call.cancel();
    }
  }

  /** A client-streaming method, one attempt: `messages` are written as the channel takes
   * them (their producer waits while it is full), then the stream is half-closed. */
  async clientStream<K extends MethodName>(name: K, messages: AsyncIterable<RequestOf<K>>,
    mesh: string | undefined): Promise<ResponseOf<K>> {
    const m = this.methods[name];
    let answered = false;
    let call!: grpc.ClientWritableStream<RequestOf<K>>;
    const answer = new Promise<ResponseOf<K>>((resolve, reject) => {
      call = this.client.makeClientStreamRequest(m.path, m.requestSerialize,
        m.responseDeserialize, this.metadata(mesh), this.options(true), (error, response) => {
          answered = true;
          if (error) reject(fromGrpcError(error, name));
          else if (response === undefined) reject(new Error(`${name}: no answer and no error`));
          else resolve(response);
        });
    });
    answer.catch(() => undefined);  // awaited below; no unhandled rejection meanwhile
    try {
      for await (const message of messages) {
        if (answered) break;  // refused early: the answer says why
        if (!call.write(message)) {
          await new Promise<void>((resolve) => {
            const go = (): void => {
              call.off("drain", go);
              call.off("error", go);
              resolve();
            };
            call.on("drain", go);
            call.on("error", go);
          });
        }
      }
    } catch (e) {
      // The payload could not be produced (a file gone): cancel, so that the
      // server registers nothing, and say why.
      call.cancel();
      throw e;
    }
    call.end();
    return answer;
  }

  /** run() retried per the policy (for streams, whose reading is the caller's). */
  call<T>(run: () => Promise<T>): Promise<T> {
    return withRetries(this.retry, run);
  }
}
