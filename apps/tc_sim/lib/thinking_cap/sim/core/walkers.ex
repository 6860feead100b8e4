defmodule ThinkingCap.Sim.Core.Walkers do
  @moduledoc false
  # One step of the walkers: people (discs) walking routes of points at
  # their speed, back and forth (or round, `loop: true`). They step one
  # after the other in order of id, each seeing the robots where they now
  # stand and the walkers before it where they moved; one waits while its
  # next step would come within 0.05 m of a robot or another walker. The
  # step itself is in C (Raycast.walkers_step/4: a grid of buckets, so a
  # walker looks only at its 3 x 3 buckets, linear in robots + walkers);
  # the routes' legs are kept here.

  alias ThinkingCap.Sim.Raycast

  @gap 0.05

  @doc """
  Steps every walker (`%{id => walker}`) by `dt` seconds among the robots,
  given as `{x, y, radius}` tuples or packed, three native float64 each.
  """
  @spec step(%{term() => map()}, [{number(), number(), number()}] | binary(), number()) ::
          %{term() => map()}
  def step(walkers, _robots, _dt) when map_size(walkers) == 0, do: walkers

  def step(walkers, robots, dt) when is_list(robots) do
    packed =
      for {x, y, r} <- robots,
          into: <<>>,
          do: <<x * 1.0::float-native-64, y * 1.0::float-native-64, r * 1.0::float-native-64>>

    step(walkers, packed, dt)
  end

  def step(walkers, robots, dt) when is_binary(robots) do
    ids = walkers |> Map.keys() |> Enum.sort()

    moving =
      for id <- ids, into: <<>> do
        %{at: {x, y}, radius: r, speed: v} = w = Map.fetch!(walkers, id)
        {tx, ty} = elem(w.route, w.leg)

        <<x * 1.0::float-native-64, y * 1.0::float-native-64, r * 1.0::float-native-64,
          tx * 1.0::float-native-64, ty * 1.0::float-native-64, v * 1.0::float-native-64>>
      end

    placed = Raycast.walkers_step(robots, moving, dt * 1.0, @gap)

    {walkers, <<>>} =
      Enum.reduce(ids, {walkers, placed}, fn id,
                                             {acc,
                                              <<x::float-native-64, y::float-native-64,
                                                what::float-native-64, rest::binary>>} ->
        w = Map.fetch!(acc, id)

        w =
          case what do
            2.0 -> next_leg(%{w | at: elem(w.route, w.leg)})
            1.0 -> %{w | at: {x, y}}
            _waited -> w
          end

        {Map.put(acc, id, w), rest}
      end)

    walkers
  end

  defp next_leg(%{leg: leg, dir: dir, route: route} = w) do
    n = tuple_size(route)

    cond do
      w.loop -> %{w | leg: rem(leg + 1, n)}
      leg + dir >= 0 and leg + dir < n -> %{w | leg: leg + dir}
      true -> %{w | leg: leg - dir, dir: -dir}
    end
  end
end
