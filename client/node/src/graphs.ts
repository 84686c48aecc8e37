// A graph's operation: requested, watched until it is ready, failed or
// cancelled, with each state the server streams passed to a progress
// callback on the way.
import { GraphFailedError } from "./errors";
import type { Transport } from "./transport";
import { Graph, graphFromWire, GraphState } from "./types";
import type { GraphSelectorMsg } from "./wire";

/** The graph's states as the server streams them (WatchGraph): every progress change until
 * it is ready, failed or cancelled. No deadline: `timeout` bounds calls, not a build. Leaving
 * the loop early cancels the watch. */
export async function* watchGraph(transport: Transport,
  graph: GraphSelectorMsg): AsyncGenerator<Graph, void, undefined> {
  for await (const g of transport.stream("WatchGraph", { graph }, graph.mesh, false)) {
    yield graphFromWire(g);
  }
}

/** RequestGraph, and with `wait` a watch until the graph is done (READY, or a
 * GraphFailedError). */
export async function requestGraph(transport: Transport, graph: GraphSelectorMsg, wait: boolean,
  progress?: (graph: Graph) => void): Promise<Graph> {
  let g = graphFromWire(await transport.unary("RequestGraph", { graph }, graph.mesh));
  // Under memory pressure a graph can be evicted again before this client
  // sees it ready; asking again brings it back from its file.
  for (let round = 0; wait && round < 10; round++) {
    // The epsilon the server resolved (the default's, for 0) names the graph.
    const named = { ...graph, epsilon: g.epsilon };
    const start = g;
    g = await transport.call(async () => {
      let last = start;
      for await (const state of watchGraph(transport, named)) {
        last = state;
        progress?.(state);
      }
      return last;
    });
    if (g.state !== GraphState.EVICTED) break;
    g = graphFromWire(await transport.unary("RequestGraph", { graph }, graph.mesh));
  }
  if (wait && g.state !== GraphState.READY) throw new GraphFailedError(g, GraphState[g.state]);
  return g;
}
