defmodule ThinkingCap.Dashboard.Core.Download do
  @moduledoc false
  # The yaws appmod of `/dumps/ROBOT/NAME?token=TOKEN`: a black-box dump
  # downloaded, behind the same rules as the page's socket (Core.Appmod):
  # the Origin header when a browser sends one, the access token unless
  # `public_view` is on. The robot must be one the dashboard knows (no
  # atom is made from the URL) and NAME a dump its black box lists
  # (Dashboard.Dumps.file/2: a file name looked up among the dumps, never
  # a path opened as given). Every refusal is a plain-text line saying
  # why. The file is streamed in chunks (chunked transfer), each written
  # before the next is read, so a large dump never sits in memory and a
  # client that goes away stops the reading.

  import ThinkingCap.Dashboard.Core.Records
  alias ThinkingCap.Dashboard.Core.Access
  alias ThinkingCap.Dashboard.{Control, Dumps}

  @chunk 65_536

  @doc false
  def out(arg) do
    config = ThinkingCap.Dashboard.config()

    with :ok <- running(config),
         :ok <- method(arg),
         :ok <- origin(arg, config),
         :ok <- token(arg, config),
         {:ok, robot, name} <- path(arg),
         {:ok, robot} <- robot(robot),
         {:ok, dump} <- dump(robot, name) do
      serve(dump)
    else
      {:refuse, status, message} -> refuse(status, message)
    end
  end

  defp running(nil), do: {:refuse, 503, "the dashboard is not running"}
  defp running(_config), do: :ok

  defp method(arg) do
    case http_request(arg(arg, :req), :method) do
      :GET -> :ok
      m -> {:refuse, 405, "a dump is downloaded with GET, not #{m}"}
    end
  end

  defp origin(arg, config) do
    case :yaws_api.get_header(arg(arg, :headers), "origin") do
      :undefined ->
        :ok

      origin ->
        if Access.origin_allowed?(to_string(origin), config),
          do: :ok,
          else: {:refuse, 403, "origin #{origin} is not allowed"}
    end
  end

  defp token(arg, config) do
    if Access.valid_token?(Access.query(arg)["token"], config.token) or config.public_view,
      do: :ok,
      else:
        {:refuse, 401,
         "downloading a dump needs the access token (the URL printed at start has it)"}
  end

  # the path after /dumps: exactly ROBOT/NAME, each decoded once
  defp path(arg) do
    rest = arg |> arg(:appmoddata) |> to_string()

    with [robot, name] <- String.split(String.trim_leading(rest, "/"), "/"),
         {:ok, robot} <- decode(robot),
         {:ok, name} <- decode(name) do
      {:ok, robot, name}
    else
      _ ->
        {:refuse, 400,
         "a dump is downloaded from /dumps/ROBOT/NAME, not #{inspect(arg(arg, :server_path) |> to_string(), printable_limit: 120)}"}
    end
  end

  defp decode(segment) do
    decoded = URI.decode(segment)
    if String.valid?(decoded), do: {:ok, decoded}, else: :error
  rescue
    ArgumentError -> :error
  end

  defp robot(name) do
    case Control.robot(name) do
      {:ok, robot} -> {:ok, robot}
      {:error, reason} -> {:refuse, 404, reason}
    end
  end

  defp dump(robot, name) do
    case Dumps.file(robot, name) do
      {:ok, dump} -> {:ok, dump}
      {:error, "no dump" <> _ = reason} -> {:refuse, 404, reason}
      {:error, reason} -> {:refuse, 400, reason}
    end
  end

  defp serve(dump) do
    name = Path.basename(dump.path)

    # yaws takes header names and values as charlists
    headers = [
      {:header, {~c"Content-Disposition", ~c"attachment; filename=\"#{name}\""}},
      {:header, {~c"Cache-Control", ~c"no-store"}},
      {:header, {~c"X-Content-Type-Options", ~c"nosniff"}}
    ]

    if File.regular?(dump.path) do
      yaws = self()
      spawn(fn -> stream(yaws, dump.path) end)
      [{:status, 200} | headers] ++ [{:streamcontent, ~c"application/octet-stream", ""}]
    else
      refuse(404, "no dump #{inspect(name)} of #{dump.robot}: the file is gone")
    end
  end

  # reads a chunk, hands it to yaws and waits until it is written (or the
  # client is gone), then the next
  defp stream(yaws, path) do
    ref = Process.monitor(yaws)

    case File.open(path, [:read, :binary, :raw]) do
      {:ok, file} ->
        send_chunks(yaws, ref, file)
        File.close(file)

      {:error, _gone} ->
        :yaws_api.stream_chunk_end(yaws)
    end
  end

  defp send_chunks(yaws, ref, file) do
    case :file.read(file, @chunk) do
      {:ok, data} ->
        :yaws_api.stream_chunk_deliver_blocking(yaws, data)

        receive do
          {:DOWN, ^ref, :process, _, _} -> :gone
        after
          0 -> send_chunks(yaws, ref, file)
        end

      _eof_or_error ->
        :yaws_api.stream_chunk_end(yaws)
    end
  end

  defp refuse(status, message),
    do: [{:status, status}, {:content, ~c"text/plain", String.to_charlist(message <> "\n")}]
end
