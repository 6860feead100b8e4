defmodule ThinkingCap.Dashboard.Rosbridge.WorldMap do
  @moduledoc false
  # `/map`: the dashboard's world (its `world` option, a WDF path or
  # struct) as occupancy cells. A WDF that imports a ROS map gives that
  # map's cells as they are (−1 unknown, 0..100); otherwise its walls,
  # obstacles and closed doors are rasterized at 5 cm
  # (ThinkingCap.Navigation.Maps.grid_from_wdf/2: 100 blocked, 0 free). The
  # doors are drawn as the WDF states them, not as they are now.
  #
  # The cells are made once per world (a WDF file: until it changes) and
  # kept, so clients subscribing to /map again and again cost nothing but
  # the sending; `allow_send?/0` bounds that too, for the whole node.

  alias ThinkingCap.Config
  alias ThinkingCap.Config.{RosMap, WDF}
  alias ThinkingCap.Navigation.Maps

  @type cells :: %{
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float(), float()},
          data: binary()
        }

  @doc "The cells of the world, or why there are none."
  @spec cells(term()) :: {:ok, cells()} | {:error, String.t()}
  def cells(nil), do: {:error, "the dashboard has no world: no /map"}

  def cells(path) when is_binary(path) do
    key =
      case File.stat(path, time: :posix) do
        {:ok, stat} -> {path, stat.mtime, stat.size}
        {:error, _} -> {path, nil, nil}
      end

    cached(key, fn -> read_cells(path) end)
  end

  def cells(%WDF{} = wdf), do: cached(:erlang.phash2(wdf), fn -> make_cells(wdf) end)

  def cells(_other), do: {:error, "the dashboard's world is not a WDF"}

  @cache {__MODULE__, :cells}

  # one world at a time (a node has one dashboard)
  defp cached(key, make) do
    case :persistent_term.get(@cache, nil) do
      {^key, cells} ->
        cells

      _other ->
        cells = make.()
        if match?({:ok, _}, cells), do: :persistent_term.put(@cache, {key, cells})
        cells
    end
  end

  @sends {__MODULE__, :sends}
  @sends_per_second 10

  @doc """
  Whether a map may be sent now: at most #{@sends_per_second} a second on
  this node, whoever asks (a map is the largest message there is).
  """
  @spec allow_send?() :: boolean()
  def allow_send? do
    counters =
      case :persistent_term.get(@sends, nil) do
        nil ->
          counters = :atomics.new(2, signed: true)
          :persistent_term.put(@sends, counters)
          counters

        counters ->
          counters
      end

    second = System.monotonic_time(:second)

    if :atomics.get(counters, 1) != second do
      :atomics.put(counters, 1, second)
      :atomics.put(counters, 2, 0)
    end

    :atomics.add_get(counters, 2, 1) <= @sends_per_second
  end

  defp read_cells(path) do
    case Config.read(path) do
      {:ok, %WDF{} = wdf} ->
        make_cells(wdf)

      {:ok, _other} ->
        {:error, "#{path} is not a WDF"}

      {:error, errors} ->
        {:error, "the world could not be read: " <> Config.format_errors(errors)}
    end
  end

  defp make_cells(%WDF{grid: %RosMap{} = map}) do
    {:ok,
     %{
       width: map.width,
       height: map.height,
       resolution: map.resolution,
       origin: map.origin,
       data: map.data
     }}
  end

  defp make_cells(%WDF{} = wdf) do
    grid = Maps.grid_from_wdf(wdf)
    {ox, oy} = grid.origin
    data = for <<c <- grid.cells>>, into: <<>>, do: if(c == 0, do: <<0>>, else: <<100>>)

    {:ok,
     %{
       width: grid.width,
       height: grid.height,
       resolution: grid.resolution,
       origin: {ox, oy, 0.0},
       data: data
     }}
  rescue
    e in ArgumentError -> {:error, "the world could not be rasterized: #{Exception.message(e)}"}
  end
end
